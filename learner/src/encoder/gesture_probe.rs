//! Probes of the gesture input (`learner probe-gesture`, spawned by `orchestrator gesture probe`):
//! does what a policy is given at the start of a program say where the target is, and in which
//! form? Each input is fitted to the target's bearing from the robot (cos, sin) on the training
//! split's programs and scored on the val split's, whose rooms it never saw:
//!
//! - **ridge**: linear, in the dual form, the penalty chosen on a fifth of the training rooms;
//!   what the policy's first layer could read directly;
//! - **MLP**: two hidden layers of 256 (ReLU), Adam at PPO's rate (3e-4), the number of epochs
//!   chosen on the same fifth;
//!   what a few layers can compute, such as turning an arm's direction by the person's facing;
//! - **per frame**, for the inputs made of frames: the policy's per-frame gesture network
//!   (`model.gesture_network = "per_frame"`: one small network shared by the 100 frames, pooled
//!   over time, one layer to 256) and a linear output, trained as the MLP on the raw frames — what
//!   that network can read when told the answer.
//!
//! No policy, no reward: an upper bound on what the gesture can give the policy, and the form
//! it gives it in.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor, nn, nn::Module, nn::OptimizerConfig};

use farm::config::GestureNetwork;
use shm_schema::GESTURE_FRAMES;

use super::probe::{Ridge, angle_error, degrees, standardise};
use crate::net::gesture_net::GestureNet;

/// The ridge penalties tried (relative to the inputs' mean variance): wider than the encoder
/// probe's, whose ends the pose (100) and the body points (0.001) chose on the default dataset.
const PENALTIES: [f64; 11] = [1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0, 1e3, 1e4];

const KEY_MLP: u64 = 0x6E57_0200;
const HIDDEN: i64 = 256;
const BATCH: i64 = 256;

/// What to probe.
#[derive(Clone, Debug)]
pub struct GestureProbeOptions {
    /// The file `orchestrator gesture probe` writes.
    pub data: PathBuf,
    pub seed: u64,
    /// Passes of the MLP over the training programs (the best on the chosen fifth is kept).
    pub epochs: usize,
    /// The same for the per-frame network (a hundred times the MLP's work per program).
    pub per_frame_epochs: usize,
    pub threads: i32,
}

/// One input's figures on the held-out programs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InputProbe {
    pub input: String,
    pub features: usize,
    /// Mean error of the bearing (degrees) and how often the side (target left or right of
    /// the robot's heading) is right, by the ridge probe and the MLP.
    pub ridge_error_deg: f64,
    pub ridge_side: f64,
    pub ridge_lambda: f64,
    pub mlp_error_deg: f64,
    pub mlp_side: f64,
    pub mlp_epochs: usize,
    /// The per-frame gesture network's, for inputs made of frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_frame: Option<PerFrameProbe>,
}

/// The per-frame gesture network's figures on the held-out programs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PerFrameProbe {
    pub error_deg: f64,
    pub side: f64,
    pub epochs: usize,
}

/// The report `probe-gesture` writes (`OUT.json`, and `OUT.md` as a table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GestureProbeReport {
    pub seed: u64,
    pub training_programs: usize,
    pub held_out_programs: usize,
    /// Always answering the training programs' mean bearing, and the more common side.
    pub baseline_error_deg: f64,
    pub baseline_side: f64,
    /// Held-out programs whose target is within 45° of the robot's heading at the start.
    pub ahead_share: f64,
    pub probes: Vec<InputProbe>,
}

impl GestureProbeReport {
    pub fn table(&self) -> String {
        let mut s = format!(
            "{} training programs, {} held-out programs (other rooms); always the mean bearing: {:.1}°, \
             the more common side: {:.3}; target within 45° of the heading at the start: {:.1}%\n\n\
             | input | values | ridge: error (°) | ridge: side | MLP: error (°) | MLP: side | per frame: error (°) | per frame: side |\n\
             |---|---:|---:|---:|---:|---:|---:|---:|\n",
            self.training_programs,
            self.held_out_programs,
            self.baseline_error_deg,
            self.baseline_side,
            100.0 * self.ahead_share
        );
        for p in &self.probes {
            let per_frame =
                p.per_frame.as_ref().map_or("— | —".to_string(), |f| format!("{:.1} | {:.3}", f.error_deg, f.side));
            s += &format!(
                "| {} | {} | {:.1} | {:.3} | {:.1} | {:.3} | {per_frame} |\n",
                p.input, p.features, p.ridge_error_deg, p.ridge_side, p.mlp_error_deg, p.mlp_side
            );
        }
        s
    }
}

#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct GestureProbeError {
    file: String,
    message: String,
}

/// The mean of a tensor's values (booleans count as 0 and 1).
fn mean(t: &Tensor) -> f64 {
    t.to_kind(Kind::Double).mean(Kind::Double).double_value(&[])
}

/// One input probed: its name, its columns `[N, D]` (f64) and, for an input made of frames, the
/// same values as `[N, 100, d]`.
struct Input {
    name: &'static str,
    columns: Tensor,
    frames: Option<Tensor>,
}

/// The inputs probed, from the file's tensors.
fn inputs(t: &std::collections::HashMap<String, Tensor>) -> Vec<Input> {
    let (muscles, keypoints, person) = (&t["muscles"], &t["keypoints"], &t["person"]);
    let n = person.size()[0];
    let frames = |x: &Tensor| Some(x.view([n, GESTURE_FRAMES as i64, -1]));
    // head, hips and both shoulders of the ten body points: where the person stands and faces,
    // without the arms
    let points = keypoints.view([n, GESTURE_FRAMES as i64, 10, 3]);
    let body = Tensor::cat(&[points.narrow(2, 0, 3), points.narrow(2, 6, 1)], 2).reshape([n, -1]);
    // per frame, the pose goes with every frame (as the policy's pose input goes with every step)
    let with_pose = Tensor::cat(
        &[
            muscles.view([n, GESTURE_FRAMES as i64, -1]),
            person.unsqueeze(1).expand([n, GESTURE_FRAMES as i64, -1], false),
        ],
        2,
    );
    let input = |name, columns: Tensor, frames| Input { name, columns, frames };
    vec![
        input("the person's pose (right, forward, cos and sin of their facing)", person.shallow_clone(), None),
        input("the muscles (the dissertation's input)", muscles.shallow_clone(), frames(muscles)),
        input("the muscles + the person's pose", Tensor::cat(&[muscles, person], 1), Some(with_pose)),
        input("body points without the arms (head, hips, shoulders)", body.shallow_clone(), frames(&body)),
        input("the ten body points (`gesture_input = \"keypoints\"`)", keypoints.shallow_clone(), frames(keypoints)),
    ]
}

/// Probes every input; writes `out.json` and `out.md`, prints the table.
pub fn probe_gesture(o: &GestureProbeOptions, out: &Path) -> Result<GestureProbeReport, GestureProbeError> {
    let file = o.data.display().to_string();
    let err = |message: String| GestureProbeError { file: file.clone(), message };
    tch::set_num_threads(o.threads);
    let t: std::collections::HashMap<String, Tensor> = Tensor::read_safetensors(&o.data)
        .map_err(|e| err(format!("cannot read: {e}")))?
        .into_iter()
        .map(|(k, v)| (k, v.to_kind(Kind::Double)))
        .collect();
    for name in ["muscles", "keypoints", "person", "target", "room", "held_out"] {
        if !t.contains_key(name) {
            return Err(err(format!("no tensor `{name}`: not a file of `orchestrator gesture probe`")));
        }
    }
    let held_flag = Vec::<f64>::try_from(&t["held_out"]).map_err(|e| err(format!("held_out: {e}")))?;
    let room = Vec::<f64>::try_from(&t["room"]).map_err(|e| err(format!("room: {e}")))?;
    let target = &t["target"];
    let bearing = target.select(1, 0).atan2(&target.select(1, 1));
    let y = Tensor::stack(&[bearing.cos(), bearing.sin()], 1);
    let truth = bearing.rad2deg();
    let (held, train): (Vec<i64>, Vec<i64>) = (0..held_flag.len() as i64).partition(|&i| held_flag[i as usize] > 0.5);
    // a fifth of the training rooms chooses the penalty and the epochs
    let (choose, fit): (Vec<i64>, Vec<i64>) = train.iter().partition(|&&i| room[i as usize] as i64 % 5 == 0);
    if held.is_empty() || choose.is_empty() || fit.is_empty() {
        return Err(err("the probes need held-out programs and programs of at least two training rooms".into()));
    }
    let ix = |v: &[i64]| Tensor::from_slice(v);
    let (train_t, held_t, choose_t, fit_t) = (ix(&train), ix(&held), ix(&choose), ix(&fit));
    let want = truth.index_select(0, &held_t);
    let average = degrees(&y.index_select(0, &train_t).mean_dim(0, true, Kind::Double)).expand_as(&want);
    let side_of = |deg: &Tensor| deg.sign();
    let left = mean(&side_of(&truth.index_select(0, &train_t)).lt(0.0));
    let common = if left > 0.5 { -1.0 } else { 1.0 };
    let baseline_side = mean(&side_of(&want).eq(common));
    let ahead_share = mean(&want.abs().le(45.0));

    let sets = Sets { y: &y, truth: &truth, train: &train_t, held: &held_t, fit: &fit_t, choose: &choose_t };
    let mut probes = Vec::new();
    for input in inputs(&t) {
        probes.push(one_input(o, input, &sets));
    }
    let report = GestureProbeReport {
        seed: o.seed,
        training_programs: train.len(),
        held_out_programs: held.len(),
        baseline_error_deg: mean(&angle_error(&average, &want)),
        baseline_side,
        ahead_share,
        probes,
    };
    super::probe::write_report(out, &report, &report.table())
        .map_err(|(file, message)| GestureProbeError { file, message })?;
    Ok(report)
}

/// The programs' targets (as unit vectors and in degrees) and the index sets of the splits.
struct Sets<'a> {
    y: &'a Tensor,
    truth: &'a Tensor,
    train: &'a Tensor,
    held: &'a Tensor,
    /// The training rooms' four fifths that fit, and the fifth that chooses.
    fit: &'a Tensor,
    choose: &'a Tensor,
}

/// The probes of one input: ridge, an MLP, and (for frames) the per-frame network.
fn one_input(o: &GestureProbeOptions, Input { name, columns, frames }: Input, s: &Sets) -> InputProbe {
    let (y, truth) = (s.y, s.truth);
    let (train_t, held_t, fit_t, choose_t) = (s.train, s.held, s.fit, s.choose);
    let want = truth.index_select(0, held_t);
    let side_of = |deg: &Tensor| deg.sign();
    let right_share = |deg: &Tensor, want: &Tensor| mean(&side_of(deg).eq_tensor(&side_of(want)));
    let x = standardise(&columns, train_t).to_kind(Kind::Double);
    let d = x.size()[1] as f64;
    let rows = |on: &Tensor| x.index_select(0, on);
    // ridge: penalty on the chosen fifth, then fitted on every training program
    let r = Ridge::new(&rows(fit_t), &y.index_select(0, fit_t));
    let (xc, wc) = (rows(choose_t), truth.index_select(0, choose_t));
    let e = |l: f64| mean(&angle_error(&degrees(&r.predict(&xc, l * d)), &wc));
    let lambda = *PENALTIES.iter().min_by(|&&a, &&b| e(a).total_cmp(&e(b))).expect("penalties");
    let ridge = degrees(&Ridge::new(&rows(train_t), &y.index_select(0, train_t)).predict(&rows(held_t), lambda * d));
    let split = (fit_t, choose_t, held_t);
    let (mlp, epochs) = fit_probe(&x, y, truth, split, o, |root, d| {
        nn::seq()
            .add(nn::linear(root / "l1", d, HIDDEN, Default::default()))
            .add_fn(|t| t.relu())
            .add(nn::linear(root / "l2", HIDDEN, HIDDEN, Default::default()))
            .add_fn(|t| t.relu())
            .add(nn::linear(root / "out", HIDDEN, 2, Default::default()))
    });
    let per_frame = frames.map(|f| {
        let o = &GestureProbeOptions { epochs: o.per_frame_epochs, ..o.clone() };
        let (bearing, epochs) = fit_probe(&f, y, truth, split, o, |root, d| {
            let net = GestureNet::new(&(root / "gesture"), GestureNetwork::PerFrame, d, 0, HIDDEN);
            let out = nn::linear(root / "out", HIDDEN, 2, Default::default());
            nn::func(move |g| net.forward(g).apply(&out))
        });
        PerFrameProbe { error_deg: mean(&angle_error(&bearing, &want)), side: right_share(&bearing, &want), epochs }
    });
    let p = InputProbe {
        input: name.to_string(),
        features: d as usize,
        ridge_error_deg: mean(&angle_error(&ridge, &want)),
        ridge_side: right_share(&ridge, &want),
        ridge_lambda: lambda,
        mlp_error_deg: mean(&angle_error(&mlp, &want)),
        mlp_side: right_share(&mlp, &want),
        mlp_epochs: epochs,
        per_frame,
    };
    let per_frame =
        p.per_frame.as_ref().map_or(String::new(), |f| format!(", per frame {:.1}° (side {:.3})", f.error_deg, f.side));
    println!(
        "{name}: ridge {:.1}° (side {:.3}), MLP {:.1}° (side {:.3}, {} epochs){per_frame}",
        p.ridge_error_deg, p.ridge_side, p.mlp_error_deg, p.mlp_side, p.mlp_epochs
    );
    p
}

/// A network probe (built by `build` from the inputs' last dimension, seeded): fitted on `fit`
/// to the bearing's (cos, sin), its epoch chosen on `choose`; that epoch's bearings (degrees) for
/// `held`, and the epoch.
fn fit_probe<M: Module>(
    x: &Tensor,
    y: &Tensor,
    truth: &Tensor,
    (fit, choose, held): (&Tensor, &Tensor, &Tensor),
    o: &GestureProbeOptions,
    build: impl FnOnce(&nn::Path, i64) -> M,
) -> (Tensor, usize) {
    let x = x.to_kind(Kind::Float);
    let (xf, yf) = (x.index_select(0, fit), y.index_select(0, fit).to_kind(Kind::Float));
    let (xc, xh) = (x.index_select(0, choose), x.index_select(0, held));
    let wc = truth.index_select(0, choose);
    let vs = nn::VarStore::new(Device::Cpu);
    let d = *x.size().last().expect("a dimension");
    let net = crate::device::seeded(farm::seed::mix(o.seed, &[KEY_MLP]) as i64, || build(&vs.root(), d));
    let mut opt = nn::Adam { wd: 1e-4, ..Default::default() }.build(&vs, 3e-4).expect("Adam");
    let mut rng = farm::seed::rng(o.seed, &[KEY_MLP, 1]);
    let n = xf.size()[0];
    let mut best = (f64::INFINITY, Tensor::zeros([xh.size()[0]], (Kind::Double, Device::Cpu)), 0);
    for epoch in 1..=o.epochs {
        let mut order: Vec<i64> = (0..n).collect();
        rand::seq::SliceRandom::shuffle(order.as_mut_slice(), &mut rng);
        for batch in order.chunks(BATCH as usize) {
            let b = Tensor::from_slice(batch);
            let loss = net.forward(&xf.index_select(0, &b)).mse_loss(&yf.index_select(0, &b), tch::Reduction::Mean);
            opt.backward_step(&loss);
        }
        let (c, h) = tch::no_grad(|| (net.forward(&xc), net.forward(&xh)));
        let e = mean(&angle_error(&degrees(&c.to_kind(Kind::Double)), &wc));
        if e < best.0 {
            best = (e, degrees(&h.to_kind(Kind::Double)), epoch);
        }
    }
    (best.1, best.2)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic probe file where the person's pose says where the target is (the target 2 m
    /// ahead of the person, who faces it), the muscles are noise, and the body points hold the
    /// target's bearing in ten frames that start anywhere: the pose's probes find the bearing,
    /// the muscles' do not beat always answering the mean, the per-frame network reads the
    /// bearing from the frames that hold it.
    #[test]
    fn the_probes_find_what_an_input_holds() {
        let dir = tempfile::tempdir().unwrap();
        let (n, held) = (600i64, 150i64);
        let opts = (Kind::Float, Device::Cpu);
        let (person, muscles, noise, starts) = crate::device::seeded(3, || {
            let xz = Tensor::rand([n, 2], opts) * 6.0 - 3.0;
            let facing = Tensor::rand([n], opts) * std::f64::consts::TAU;
            let person = Tensor::cat(&[xz, facing.cos().unsqueeze(1), facing.sin().unsqueeze(1)], 1);
            let starts = Tensor::randint(90, [n], (Kind::Int64, Device::Cpu));
            (person, Tensor::randn([n, 500], opts), Tensor::randn([n, 100, 30], opts) * 0.1, starts)
        });
        // the target 2 m along the person's facing (sin: right, cos: forward), relative to the robot
        let target = Tensor::stack(
            &[person.select(1, 0) + person.select(1, 3) * 2.0, person.select(1, 1) + person.select(1, 2) * 2.0],
            1,
        );
        let bearing = target.select(1, 0).atan2(&target.select(1, 1));
        let pointing = Tensor::stack(&[bearing.cos(), bearing.sin(), bearing.ones_like()], 1);
        let starts = Vec::<i64>::try_from(&starts).unwrap();
        for (i, &k) in starts.iter().enumerate() {
            let mut frames = noise.get(i as i64).narrow(0, k, 10).narrow(1, 0, 3);
            frames.copy_(&pointing.get(i as i64).expand([10, 3], false));
        }
        let keypoints = noise.view([n, 3000]);
        let room = Tensor::arange(n, (Kind::Int, Device::Cpu)).remainder(40);
        let held_out = Tensor::arange(n, (Kind::Int, Device::Cpu)).ge(n - held).to_kind(Kind::Uint8);
        let data = dir.path().join("g.gestures");
        Tensor::write_safetensors(
            &[
                ("muscles", &muscles.to_kind(Kind::Half)),
                ("keypoints", &keypoints.to_kind(Kind::Half)),
                ("person", &person),
                ("target", &target),
                ("room", &room),
                ("held_out", &held_out),
            ],
            &data,
        )
        .unwrap();
        let o = GestureProbeOptions { data, seed: 1, epochs: 40, per_frame_epochs: 10, threads: 1 };
        let r = probe_gesture(&o, &dir.path().join("g")).unwrap();
        assert_eq!((r.training_programs, r.held_out_programs), ((n - held) as usize, held as usize));
        let by = |s: &str| r.probes.iter().find(|p| p.input.starts_with(s)).unwrap();
        let (pose, noise, points) = (by("the person's pose"), by("the muscles (the"), by("the ten body points"));
        assert!(pose.mlp_error_deg < 20.0 && pose.mlp_side > 0.85, "{pose:?}");
        assert!(pose.per_frame.is_none(), "the pose is not made of frames");
        let per_frame = points.per_frame.as_ref().unwrap();
        assert!(per_frame.error_deg < 20.0 && per_frame.side > 0.85, "{points:?}");
        assert!(pose.ridge_error_deg < r.baseline_error_deg - 20.0, "{pose:?}, mean {:.1}°", r.baseline_error_deg);
        assert!(noise.ridge_error_deg > r.baseline_error_deg - 15.0 && noise.ridge_side < 0.7, "{noise:?}");
        let table = std::fs::read_to_string(dir.path().join("g.md")).unwrap();
        assert_eq!(table.lines().filter(|l| l.starts_with("| the") || l.starts_with("| body")).count(), 5);
        // not a probe file: one error naming it
        let bad = dir.path().join("bad.gestures");
        Tensor::write_safetensors(&[("person", &person)], &bad).unwrap();
        let e = probe_gesture(
            &GestureProbeOptions { data: bad.clone(), seed: 1, epochs: 1, per_frame_epochs: 1, threads: 1 },
            &bad,
        )
        .unwrap_err();
        assert!(e.to_string().contains("bad.gestures") && e.to_string().contains("muscles"), "{e}");
    }
}
