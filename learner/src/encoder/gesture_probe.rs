//! Probes of the gesture input (`learner probe-gesture`, spawned by `orchestrator gesture probe`):
//! does what a policy is given at the start of a program say where the target is, and in which
//! form? Each input is fitted to the target's bearing from the robot (cos, sin) on the training
//! split's programs and scored on the val split's, whose rooms it never saw:
//!
//! - **ridge**: linear, in the dual form, the penalty chosen on a fifth of the training rooms;
//!   what the policy's first layer could read directly;
//! - **MLP**: two hidden layers of 256 (ReLU), Adam at PPO's rate (3e-4), the number of epochs
//!   chosen on the same fifth;
//!   what a few layers can compute, such as turning an arm's direction by the person's facing.
//!
//! No policy, no reward: an upper bound on what the gesture can give the policy, and the form
//! it gives it in.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor, nn, nn::Module, nn::OptimizerConfig};

use super::probe::{Ridge, angle_error, degrees, standardise};

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
             | input | values | ridge: error (°) | ridge: side | MLP: error (°) | MLP: side |\n|---|---:|---:|---:|---:|---:|\n",
            self.training_programs,
            self.held_out_programs,
            self.baseline_error_deg,
            self.baseline_side,
            100.0 * self.ahead_share
        );
        for p in &self.probes {
            s += &format!(
                "| {} | {} | {:.1} | {:.3} | {:.1} | {:.3} |\n",
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

/// The inputs probed: name and columns `[N, D]` (f64) of the file's tensors.
fn inputs(t: &std::collections::HashMap<String, Tensor>) -> Vec<(&'static str, Tensor)> {
    let (muscles, keypoints, person) = (&t["muscles"], &t["keypoints"], &t["person"]);
    let n = person.size()[0];
    // head, hips and both shoulders of the ten body points: where the person stands and faces,
    // without the arms
    let frames = keypoints.view([n, 100, 10, 3]);
    let body = Tensor::cat(&[frames.narrow(2, 0, 3), frames.narrow(2, 6, 1)], 2).reshape([n, -1]);
    vec![
        ("the person's pose (right, forward, cos and sin of their facing)", person.shallow_clone()),
        ("the muscles (the dissertation's input)", muscles.shallow_clone()),
        ("the muscles + the person's pose", Tensor::cat(&[muscles, person], 1)),
        ("body points without the arms (head, hips, shoulders)", body),
        ("the ten body points (`gesture_input = \"keypoints\"`)", keypoints.shallow_clone()),
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
    let right_share = |deg: &Tensor, want: &Tensor| mean(&side_of(deg).eq_tensor(&side_of(want)));
    let left = mean(&side_of(&truth.index_select(0, &train_t)).lt(0.0));
    let common = if left > 0.5 { -1.0 } else { 1.0 };
    let baseline_side = mean(&side_of(&want).eq(common));
    let ahead_share = mean(&want.abs().le(45.0));

    let mut probes = Vec::new();
    for (name, x) in inputs(&t) {
        let x = standardise(&x, &train_t).to_kind(Kind::Double);
        let d = x.size()[1] as f64;
        let rows = |on: &Tensor| x.index_select(0, on);
        // ridge: penalty on the chosen fifth, then fitted on every training program
        let r = Ridge::new(&rows(&fit_t), &y.index_select(0, &fit_t));
        let (xc, wc) = (rows(&choose_t), truth.index_select(0, &choose_t));
        let e = |l: f64| mean(&angle_error(&degrees(&r.predict(&xc, l * d)), &wc));
        let lambda = *PENALTIES.iter().min_by(|&&a, &&b| e(a).total_cmp(&e(b))).expect("penalties");
        let ridge =
            degrees(&Ridge::new(&rows(&train_t), &y.index_select(0, &train_t)).predict(&rows(&held_t), lambda * d));
        let (mlp, epochs) = mlp(&x, &y, &truth, (&fit_t, &choose_t, &held_t), o);
        let p = InputProbe {
            input: name.to_string(),
            features: d as usize,
            ridge_error_deg: mean(&angle_error(&ridge, &want)),
            ridge_side: right_share(&ridge, &want),
            ridge_lambda: lambda,
            mlp_error_deg: mean(&angle_error(&mlp, &want)),
            mlp_side: right_share(&mlp, &want),
            mlp_epochs: epochs,
        };
        println!(
            "{name}: ridge {:.1}° (side {:.3}), MLP {:.1}° (side {:.3}, {} epochs)",
            p.ridge_error_deg, p.ridge_side, p.mlp_error_deg, p.mlp_side, p.mlp_epochs
        );
        probes.push(p);
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

/// The MLP probe: fitted on `fit`, its epoch chosen on `choose`; that epoch's bearings (degrees)
/// for `held`, and the epoch.
fn mlp(
    x: &Tensor,
    y: &Tensor,
    truth: &Tensor,
    (fit, choose, held): (&Tensor, &Tensor, &Tensor),
    o: &GestureProbeOptions,
) -> (Tensor, usize) {
    let x = x.to_kind(Kind::Float);
    let (xf, yf) = (x.index_select(0, fit), y.index_select(0, fit).to_kind(Kind::Float));
    let (xc, xh) = (x.index_select(0, choose), x.index_select(0, held));
    let wc = truth.index_select(0, choose);
    let vs = nn::VarStore::new(Device::Cpu);
    let root = vs.root();
    let d = x.size()[1];
    let net = crate::device::seeded(farm::seed::mix(o.seed, &[KEY_MLP]) as i64, || {
        nn::seq()
            .add(nn::linear(&root / "l1", d, HIDDEN, Default::default()))
            .add_fn(|t| t.relu())
            .add(nn::linear(&root / "l2", HIDDEN, HIDDEN, Default::default()))
            .add_fn(|t| t.relu())
            .add(nn::linear(&root / "out", HIDDEN, 2, Default::default()))
    });
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
    /// ahead of the person, who faces it) and the muscles are noise: the pose's probes find the
    /// bearing, the muscles' do not beat always answering the mean.
    #[test]
    fn the_probes_find_what_an_input_holds() {
        let dir = tempfile::tempdir().unwrap();
        let (n, held) = (600i64, 150i64);
        let opts = (Kind::Float, Device::Cpu);
        let (person, muscles, keypoints) = crate::device::seeded(3, || {
            let xz = Tensor::rand([n, 2], opts) * 6.0 - 3.0;
            let facing = Tensor::rand([n], opts) * std::f64::consts::TAU;
            let person = Tensor::cat(&[xz, facing.cos().unsqueeze(1), facing.sin().unsqueeze(1)], 1);
            (person, Tensor::randn([n, 95], opts), Tensor::randn([n, 3000], opts))
        });
        // the target 2 m along the person's facing (sin: right, cos: forward), relative to the robot
        let target = Tensor::stack(
            &[person.select(1, 0) + person.select(1, 3) * 2.0, person.select(1, 1) + person.select(1, 2) * 2.0],
            1,
        );
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
        let o = GestureProbeOptions { data, seed: 1, epochs: 40, threads: 1 };
        let r = probe_gesture(&o, &dir.path().join("g")).unwrap();
        assert_eq!((r.training_programs, r.held_out_programs), ((n - held) as usize, held as usize));
        let by = |s: &str| r.probes.iter().find(|p| p.input.starts_with(s)).unwrap();
        let (pose, noise) = (by("the person's pose"), by("the muscles (the"));
        assert!(pose.mlp_error_deg < 20.0 && pose.mlp_side > 0.85, "{pose:?}");
        assert!(pose.ridge_error_deg < r.baseline_error_deg - 20.0, "{pose:?}, mean {:.1}°", r.baseline_error_deg);
        assert!(noise.ridge_error_deg > r.baseline_error_deg - 15.0 && noise.ridge_side < 0.7, "{noise:?}");
        let table = std::fs::read_to_string(dir.path().join("g.md")).unwrap();
        assert_eq!(table.lines().filter(|l| l.starts_with("| the") || l.starts_with("| body")).count(), 5);
        // not a probe file: one error naming it
        let bad = dir.path().join("bad.gestures");
        Tensor::write_safetensors(&[("person", &person)], &bad).unwrap();
        let e = probe_gesture(&GestureProbeOptions { data: bad.clone(), seed: 1, epochs: 1, threads: 1 }, &bad)
            .unwrap_err();
        assert!(e.to_string().contains("bad.gestures") && e.to_string().contains("muscles"), "{e}");
    }
}
