//! Linear probes on frozen features (`learner probe-encoder`): what an encoder's features hold that
//! the task needs, measured the same way for every encoder, in rooms neither the encoder nor the
//! probe saw. The labels are read here only, never by a label-free encoder's training.
//!
//! - **category**: per feature cell, one linear map of the cell's standardised features to the 39
//!   cell classes (37 target categories, the person, other), cross-entropy with "other" weighed as
//!   in the semantic objective. How much of the answer key the features hold.
//! - **facing**: frames where the person is in view, the features of the 3×3 cells around the
//!   middle of the person's cells (where the person is comes from the labels, what they show from
//!   the features) → (cos, sin) of the person's facing relative to the robot, ridge regression
//!   with λ chosen on a fifth of the learning rooms. What reading a pointing arm needs: which way
//!   the person stands, in the robot's view.
//!
//! "pixels" probes the encoder's input itself (each cell's 8×8×4 values): the reference a trained
//! encoder should beat where it abstracts, and may trail where it compresses.

use std::path::{Path, PathBuf};

use farm::frame_set::{CLASS_OTHER, CLASS_PERSON, CLASSES, FrameSet};
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Reduction, Tensor, nn, nn::Module, nn::OptimizerConfig};

use super::net::{RgbdEncoder, STRIDE, encoder_input, load_weights, sha256_hex};
use super::pretrain::{OTHER_WEIGHT, frame_tensors};

const KEY_PROBE: u64 = 0xE4C0_0200;
/// Ridge penalties tried for the facing probe (times the number of features).
pub(crate) const RIDGE: [f64; 6] = [1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0];

/// What to probe.
#[derive(Clone, Debug)]
pub struct ProbeOptions {
    /// A frame set of the training split's rooms (`orchestrator encoder probe` renders one).
    pub frames: PathBuf,
    /// Encoders by name: a weights file, or None for the raw pixels.
    pub encoders: Vec<(String, Option<PathBuf>)>,
    pub seed: u64,
    /// Passes of the category probe over the training cells.
    pub epochs: usize,
    pub threads: i32,
}

/// One encoder's probe figures on the held-out rooms.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Probe {
    pub encoder: String,
    /// The weights file's sha256 (None: the raw pixels).
    pub sha256: Option<String>,
    /// Category probe: accuracy over cells showing a target or the person, over targets only,
    /// over the person's cells.
    pub category_targets_and_person: f64,
    pub category_targets: f64,
    pub category_person: f64,
    /// Facing probe: mean absolute error (degrees), the same for always answering the training
    /// mean, and how often the side (left/right of facing the robot) is right.
    pub facing_error_deg: f64,
    pub facing_baseline_deg: f64,
    pub facing_side_accuracy: f64,
    pub facing_ridge: f64,
}

/// The report `probe-encoder` writes (`OUT.json`, and `OUT.md` as a table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProbeReport {
    pub frame_set: String,
    pub frames_seed: u64,
    pub seed: u64,
    pub training_frames: usize,
    pub held_out_frames: usize,
    /// Frames with the person in view: training, held out.
    pub facing_frames: (usize, usize),
    pub held_out_rooms: Vec<u16>,
    pub probes: Vec<Probe>,
}

impl ProbeReport {
    /// The Markdown table of the probes.
    pub fn table(&self) -> String {
        let mut s = String::from(
            "| encoder | category: targets + person | targets | person | facing error (°) | always the mean (°) | facing side |\n\
             |---|---:|---:|---:|---:|---:|---:|\n",
        );
        for p in &self.probes {
            s += &format!(
                "| {} | {:.3} | {:.3} | {:.3} | {:.1} | {:.1} | {:.3} |\n",
                p.encoder,
                p.category_targets_and_person,
                p.category_targets,
                p.category_person,
                p.facing_error_deg,
                p.facing_baseline_deg,
                p.facing_side_accuracy
            );
        }
        s
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ProbeError {
    #[error(transparent)]
    Frames(#[from] farm::frame_set::FrameSetError),
    #[error(transparent)]
    Weights(#[from] super::net::EncoderFileError),
    #[error("{file}: {message}")]
    Unusable { file: String, message: String },
}

/// Features `[N, D, g, g]` of every frame: the trunk's, or the pixels of each cell.
fn features(set: &FrameSet, trunk: Option<&RgbdEncoder>) -> Tensor {
    let n = set.len() as i64;
    let (rgb, depth) = frame_tensors(set);
    tch::no_grad(|| {
        let chunks: Vec<Tensor> = (0..n)
            .step_by(256)
            .map(|at| {
                let len = (n - at).min(256);
                let x = encoder_input(&rgb.narrow(0, at, len), &depth.narrow(0, at, len));
                match trunk {
                    Some(t) => t.forward(&x),
                    None => x.pixel_unshuffle(STRIDE),
                }
            })
            .collect();
        Tensor::cat(&chunks, 0)
    })
}

/// Standardises `x` `[N, D]` by the mean and deviation of its rows `train`.
pub(crate) fn standardise(x: &Tensor, train: &Tensor) -> Tensor {
    let t = x.index_select(0, train);
    let mean = t.mean_dim(0, true, Kind::Float);
    let std = t.std_dim(0, false, true) + 1e-4;
    (x - mean) / std
}

/// The category probe: accuracies on the held-out frames' cells.
fn category_probe(f: &Tensor, class: &Tensor, train: &[i64], held: &[i64], o: &ProbeOptions) -> (f64, f64, f64) {
    let (n, d) = (f.size()[0], f.size()[1]);
    let cells = f.size()[2] * f.size()[3];
    let x = f.permute([0, 2, 3, 1]).reshape([n * cells, d]);
    let y = class.reshape([n * cells]);
    let rows = |frames: &[i64]| -> Vec<i64> { frames.iter().flat_map(|&i| (i * cells)..((i + 1) * cells)).collect() };
    let (train_rows, held_rows) = (rows(train), rows(held));
    let x = standardise(&x, &Tensor::from_slice(&train_rows));
    let vs = nn::VarStore::new(Device::Cpu);
    let linear = crate::device::seeded(farm::seed::mix(o.seed, &[KEY_PROBE]) as i64, || {
        nn::linear(vs.root(), d, CLASSES as i64, Default::default())
    });
    let mut opt = nn::Adam::default().build(&vs, 3e-3).expect("adam");
    let mut weights = vec![1f32; CLASSES as usize];
    weights[CLASS_OTHER as usize] = OTHER_WEIGHT as f32;
    let weights = Tensor::from_slice(&weights);
    let mut order = train_rows;
    for epoch in 0..o.epochs {
        order.shuffle(&mut farm::seed::rng(o.seed, &[KEY_PROBE, epoch as u64]));
        for chunk in order.chunks(4096) {
            let i = Tensor::from_slice(chunk);
            let logits = linear.forward(&x.index_select(0, &i));
            let loss = logits.cross_entropy_loss(&y.index_select(0, &i), Some(&weights), Reduction::Mean, -100, 0.0);
            opt.backward_step(&loss);
        }
    }
    tch::no_grad(|| {
        let i = Tensor::from_slice(&held_rows);
        let want = y.index_select(0, &i);
        let hit = linear.forward(&x.index_select(0, &i)).argmax(1, false).eq_tensor(&want);
        let share = |mask: Tensor| {
            let m = mask.sum(Kind::Int64).int64_value(&[]);
            hit.logical_and(&mask).sum(Kind::Int64).int64_value(&[]) as f64 / m.max(1) as f64
        };
        let person = want.eq(i64::from(CLASS_PERSON));
        let target = want.lt(i64::from(CLASS_PERSON));
        (share(target.logical_or(&person)), share(target), share(person))
    })
}

/// Degrees of the angle of (cos, sin) rows.
pub(crate) fn degrees(cs: &Tensor) -> Tensor {
    cs.select(1, 1).atan2(&cs.select(1, 0)).rad2deg()
}

/// |a − b| in degrees, wrapped to 0..180.
pub(crate) fn angle_error(a: &Tensor, b: &Tensor) -> Tensor {
    ((a - b + 540.0).remainder(360.0) - 180.0).abs()
}

/// Ridge regression of targets `y` on rows `x`: in the dual form where the features outnumber
/// the rows, else the primal. The Gram matrix is made once, each penalty is one solve.
pub(crate) struct Ridge {
    mx: Tensor,
    my: Tensor,
    /// Centred training rows `[n, d]`, centred targets `[n, 2]`, and `xc·xcᵀ` `[n, n]` (dual) or
    /// `xcᵀ·xc` `[d, d]` (primal).
    xc: Tensor,
    yc: Tensor,
    gram: Tensor,
    dual: bool,
}

impl Ridge {
    pub(crate) fn new(x: &Tensor, y: &Tensor) -> Ridge {
        let (mx, my) = (x.mean_dim(0, true, Kind::Double), y.mean_dim(0, true, Kind::Double));
        let (xc, yc) = (x - &mx, y - &my);
        let dual = xc.size()[1] > xc.size()[0];
        let gram = if dual { xc.matmul(&xc.tr()) } else { xc.tr().matmul(&xc) };
        Ridge { mx, my, xc, yc, gram, dual }
    }

    /// Predictions for the rows `x` with penalty `lambda`.
    pub(crate) fn predict(&self, x: &Tensor, lambda: f64) -> Tensor {
        let n = self.gram.size()[0];
        let a = &self.gram + Tensor::eye(n, (Kind::Double, Device::Cpu)) * lambda;
        let w = if self.dual {
            self.xc.tr().matmul(&Tensor::linalg_solve(&a, &self.yc, true))
        } else {
            Tensor::linalg_solve(&a, &self.xc.tr().matmul(&self.yc), true)
        };
        (x - &self.mx).matmul(&w) + &self.my
    }
}

/// The facing probe on frames `train` / `held` (the person in view): error, baseline, side
/// accuracy, chosen ridge. `val_room(i)` says which training frames choose the penalty.
fn facing_probe(
    f: &Tensor,
    centre: &dyn Fn(i64) -> (i64, i64),
    facing: &[f32],
    train: &[i64],
    held: &[i64],
    val_room: &dyn Fn(i64) -> bool,
) -> [f64; 4] {
    // each frame's 3×3 cells around the person (zeros past the edge), flattened: [N, 9 D]
    let padded = f.constant_pad_nd([1i64, 1, 1, 1]);
    let all: Vec<i64> = train.iter().chain(held).copied().collect();
    let windows: Vec<Tensor> = all
        .iter()
        .map(|&i| {
            let (row, col) = centre(i);
            padded.get(i).narrow(1, row, 3).narrow(2, col, 3).reshape([-1])
        })
        .collect();
    let (n, d) = (f.size()[0], 9 * f.size()[1]);
    let mut x = Tensor::zeros([n, d], (Kind::Double, Device::Cpu));
    let _ = x.index_copy_(0, &Tensor::from_slice(&all), &Tensor::stack(&windows, 0).to_kind(Kind::Double));
    let x = standardise(&x, &Tensor::from_slice(train));
    let d = x.size()[1] as f64;
    let rows = |on: &[i64]| x.index_select(0, &Tensor::from_slice(on));
    let target = |on: &[i64]| {
        let rad: Vec<f64> = on.iter().map(|&i| f64::from(facing[i as usize]).to_radians()).collect();
        let r = Tensor::from_slice(&rad);
        Tensor::stack(&[r.cos(), r.sin()], 1)
    };
    let truth = |on: &[i64]| Tensor::from_slice(&on.iter().map(|&i| f64::from(facing[i as usize])).collect::<Vec<_>>());
    let (choose, val): (Vec<i64>, Vec<i64>) = train.iter().partition(|&&i| !val_room(i));
    let lambda = if choose.is_empty() || val.is_empty() {
        1.0
    } else {
        let r = Ridge::new(&rows(&choose), &target(&choose));
        let (xv, want) = (rows(&val), truth(&val));
        let err = |l: f64| angle_error(&degrees(&r.predict(&xv, l * d)), &want).mean(Kind::Double).double_value(&[]);
        *RIDGE.iter().min_by(|&&a, &&b| err(a).total_cmp(&err(b))).expect("penalties")
    };
    let predicted = degrees(&Ridge::new(&rows(train), &target(train)).predict(&rows(held), lambda * d));
    let want = truth(held);
    let mean = degrees(&target(train).mean_dim(0, true, Kind::Double)).expand_as(&want);
    let side = predicted.sign().eq_tensor(&want.sign()).to_kind(Kind::Double).mean(Kind::Double);
    [
        angle_error(&predicted, &want).mean(Kind::Double).double_value(&[]),
        angle_error(&mean, &want).mean(Kind::Double).double_value(&[]),
        side.double_value(&[]),
        lambda,
    ]
}

/// Probes every encoder of `o`; writes `out.json` and `out.md`, prints the table.
pub fn probe(o: &ProbeOptions, out: &Path) -> Result<ProbeReport, ProbeError> {
    let set = FrameSet::read(&o.frames)?;
    let h = set.header.clone();
    let file = o.frames.display().to_string();
    let unusable = |message: String| ProbeError::Unusable { file: file.clone(), message };
    if h.classes != CLASSES || h.width as i64 / STRIDE != h.grid as i64 || h.height != h.width {
        return Err(unusable(format!(
            "frames of {}×{} with {} cells of {} classes: the probes need square frames with one cell per feature \
             ({STRIDE} pixels) and {CLASSES} classes",
            h.width, h.height, h.grid, h.classes
        )));
    }
    tch::set_num_threads(o.threads);
    let n = set.len() as i64;
    let (held, train): (Vec<i64>, Vec<i64>) = (0..n).partition(|&i| set.is_held_out(i as usize));
    if held.is_empty() || train.is_empty() {
        return Err(unusable("the probes need frames of the held-out rooms and of the others".into()));
    }
    let class = Tensor::from_slice(&set.cell_class).view([n, h.grid as i64, h.grid as i64]).to_kind(Kind::Int64);
    let cells = h.cells();
    let in_view = |i: &&i64| {
        let i = **i as usize;
        !set.person_facing[i].is_nan() && set.cell_class[i * cells..(i + 1) * cells].contains(&CLASS_PERSON)
    };
    let facing_train: Vec<i64> = train.iter().filter(in_view).copied().collect();
    let facing_held: Vec<i64> = held.iter().filter(in_view).copied().collect();
    if facing_train.len() < 10 || facing_held.is_empty() {
        return Err(unusable(format!(
            "{} training and {} held-out frames show the person: too few for the facing probe (render more frames)",
            facing_train.len(),
            facing_held.len()
        )));
    }
    let facing = (facing_train.as_slice(), facing_held.as_slice());
    let mut probes = Vec::new();
    for (name, weights) in &o.encoders {
        probes.push(one_encoder(o, &set, name, weights.as_deref(), &class, (&train, &held), facing)?);
    }
    let report = ProbeReport {
        frame_set: file.clone(),
        frames_seed: h.seed,
        seed: o.seed,
        training_frames: train.len(),
        held_out_frames: held.len(),
        facing_frames: (facing_train.len(), facing_held.len()),
        held_out_rooms: h.held_out.clone(),
        probes,
    };
    write_report(out, &report, &report.table()).map_err(|(file, message)| ProbeError::Unusable { file, message })?;
    Ok(report)
}

/// The probes of one encoder's features (`weights`; None: the raw pixels).
fn one_encoder(
    o: &ProbeOptions,
    set: &FrameSet,
    name: &str,
    weights: Option<&Path>,
    class: &Tensor,
    (train, held): (&[i64], &[i64]),
    (facing_train, facing_held): (&[i64], &[i64]),
) -> Result<Probe, ProbeError> {
    let h = &set.header;
    let val_room = |i: i64| set.rooms[i as usize] % 5 == 0;
    // the middle cell of a frame's person cells (row, column)
    let person_centre = |i: i64| {
        let g = h.grid as usize;
        let cells = &set.cell_class[i as usize * g * g..(i as usize + 1) * g * g];
        let at: Vec<usize> = (0..g * g).filter(|&k| cells[k] == CLASS_PERSON).collect();
        let mean = |f: fn(usize, usize) -> usize| {
            (at.iter().map(|&k| f(k, g)).sum::<usize>() as f64 / at.len().max(1) as f64).round() as i64
        };
        (mean(|k, g| k / g), mean(|k, g| k % g))
    };
    let vs = nn::VarStore::new(Device::Cpu);
    let (f, sha256) = match weights {
        Some(path) => {
            let trunk = RgbdEncoder::new(&(vs.root() / "trunk"));
            load_weights(path, &vs, "trunk", (h.width, h.height))?;
            let bytes = std::fs::read(path).map_err(|e| ProbeError::Unusable {
                file: path.display().to_string(),
                message: format!("cannot read: {e}"),
            })?;
            (features(set, Some(&trunk)), Some(sha256_hex(&bytes)))
        }
        None => (features(set, None), None),
    };
    let (both, targets, person) = category_probe(&f, class, train, held, o);
    let [err, base, side, lambda] =
        facing_probe(&f, &person_centre, &set.person_facing, facing_train, facing_held, &val_room);
    let p = Probe {
        encoder: name.to_string(),
        sha256,
        category_targets_and_person: both,
        category_targets: targets,
        category_person: person,
        facing_error_deg: err,
        facing_baseline_deg: base,
        facing_side_accuracy: side,
        facing_ridge: lambda,
    };
    println!(
        "{name}: category {both:.3} (targets {targets:.3}, person {person:.3}); facing error {err:.1}° \
         (always the mean {base:.1}°), side {side:.3}"
    );
    Ok(p)
}

/// A probe's report as `OUT.json` and its table as `OUT.md` (each written atomically), and the
/// table printed; else the file that could not be written, and why.
pub(super) fn write_report(out: &Path, report: &impl Serialize, table: &str) -> Result<(), (String, String)> {
    let write = |ext: &str, text: &str| {
        let p = farm::files::with_ext(out, ext);
        farm::files::write_atomic(&p, text.as_bytes())
            .map_err(|e| (p.display().to_string(), format!("cannot write: {e}")))
    };
    write("json", &(serde_json::to_string_pretty(report).expect("serialises") + "\n"))?;
    write("md", table)?;
    print!("{table}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angles_wrap_and_ridge_fits_a_line() {
        let a = Tensor::from_slice(&[170.0f64, -170.0, 10.0]);
        let b = Tensor::from_slice(&[-170.0f64, 170.0, -20.0]);
        assert_eq!(Vec::<f64>::try_from(angle_error(&a, &b)).unwrap(), vec![20.0, 20.0, 30.0]);
        let cs = Tensor::from_slice(&[0.0f64, 1.0]).view([1, 2]);
        assert!((degrees(&cs).double_value(&[0]) - 90.0).abs() < 1e-9);
        // y = 2 x0 − x1 on 40 frames of 3 features: a small penalty predicts new rows exactly
        let x = crate::device::seeded(1, || Tensor::randn([40, 3], (Kind::Double, Device::Cpu)));
        let y = (x.select(1, 0) * 2.0 - x.select(1, 1)).unsqueeze(1);
        let r = Ridge::new(&x, &y);
        let probe = Tensor::from_slice(&[1.0f64, 1.0, 5.0, 0.0, 2.0, 0.0]).view([2, 3]);
        let want = Tensor::from_slice(&[1.0f64, -2.0]).view([2, 1]);
        let got = r.predict(&probe, 1e-6);
        assert!(got.allclose(&want, 1e-4, 1e-4, false), "{got}");
        // more features than rows takes the dual form: the same predictions as the primal
        let wide = crate::device::seeded(2, || Tensor::randn([6, 9], (Kind::Double, Device::Cpu)));
        let (yw, at) = (wide.select(1, 0).unsqueeze(1), wide.narrow(0, 0, 2));
        let dual = Ridge::new(&wide, &yw).predict(&at, 0.5);
        let (mx, my) = (wide.mean_dim(0, true, Kind::Double), yw.mean_dim(0, true, Kind::Double));
        let (xc, yc) = (&wide - &mx, &yw - &my);
        let w = Tensor::linalg_solve(
            &(xc.tr().matmul(&xc) + Tensor::eye(9, (Kind::Double, Device::Cpu)) * 0.5),
            &xc.tr().matmul(&yc),
            true,
        );
        let direct = (&at - &mx).matmul(&w) + &my;
        assert!(dual.allclose(&direct, 1e-8, 1e-8, false), "dual {dual} against primal {direct}");
    }
}
