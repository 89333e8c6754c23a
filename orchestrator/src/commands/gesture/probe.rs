//! `orchestrator gesture probe`: does the referencing gesture say where the target is, for the
//! robot, before any learning of a policy? For each program it takes what a policy is given at
//! the start (the 100 × 95 muscles, or the ten body points as the robot's camera sees them, and
//! the person's pose relative to the robot) and the answer (the target's bearing from the robot),
//! writes them as one safetensors file and runs `learner probe-gesture`: ridge and small MLP probes
//! fitted on the training split's programs and scored on the val split's (other rooms).

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use clap::Args;
use half::f16;
use nalgebra::Point3;
use safetensors::{Dtype, tensor::TensorView};

use farm::config::EnvConfig;
use farm::files::with_ext;
use shm_schema::GESTURE_KEYPOINT_DIMS;
use worker::dataset::{Dataset, Verify};
use worker::gesture::{FRAMES, keypoints};
use worker::humanoid::{Humanoid, MUSCLES};
use worker::program::Program;
use worker::scene::Split;

use crate::report::progress::Bar;

#[derive(Args, Debug)]
pub struct ProbeArgs {
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    /// Output stem: STEM.json and STEM.md (and STEM.gestures while it runs).
    #[arg(long, default_value = "docs/experiments/probes/gesture-probe")]
    pub out: PathBuf,
    /// Training programs the probes learn from (the first N of the train split; 0: all).
    #[arg(long, default_value_t = 0)]
    pub train: usize,
    /// Val programs they are scored on (evenly spread over the split, so over all its rooms).
    #[arg(long, default_value_t = 2500)]
    pub held_out: usize,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Where `learner` is (default: beside this binary).
    #[arg(long)]
    pub bin_dir: Option<PathBuf>,
}

/// What a policy is given at the start of one program, and the answer.
struct Row {
    muscles: Vec<f32>,
    keypoints: Vec<f32>,
    /// The person relative to the robot: right, forward (m), cos and sin of their yaw less the robot's.
    person: [f32; 4],
    /// The target's centre relative to the robot: right, forward (m).
    target: [f32; 2],
    room: i32,
}

fn row(p: &Program, motion: Vec<f32>, env: &EnvConfig) -> anyhow::Result<Row> {
    let m = worker::gesture::Motion::from_flat(&motion).context("motion size")?;
    let pose = p.robot_start();
    let camera = pose.camera(env);
    let world = keypoints::world(&Humanoid::seeded(p.seed), &m, Point3::from(p.human_pos), p.human_yaw);
    let mut seen = vec![0.0; FRAMES * GESTURE_KEYPOINT_DIMS];
    keypoints::write_seen(&world, &camera, GESTURE_KEYPOINT_DIMS, &mut seen);
    let [right, forward, yaw] = p.person_relative(&pose);
    let (s, c) = (yaw * std::f32::consts::TAU).sin_cos();
    let t = camera.to_eye(&p.target_center());
    Ok(Row {
        muscles: motion,
        keypoints: seen,
        person: [right, forward, c, s],
        target: [t.x, t.z],
        room: p.scene_id().floorplan() as i32,
    })
}

pub fn probe(a: ProbeArgs) -> anyhow::Result<()> {
    let ds = Dataset::open(&a.dataset, Verify::Quick)?;
    let env = EnvConfig::default();
    let (train, val) = (ds.require(Split::Train)?, ds.require(Split::Val)?);
    let n_train = if a.train == 0 { train.len() } else { a.train.min(train.len()) };
    let n_held = a.held_out.min(val.len());
    anyhow::ensure!(n_train > 0 && n_held > 0, "{}: no programs to probe", a.dataset.display());
    let picks: Vec<(Split, usize)> = (0..n_train)
        .map(|i| (Split::Train, i))
        .chain((0..n_held).map(|k| (Split::Val, k * val.len() / n_held)))
        .collect();
    let bar = Bar::new("gesture inputs", picks.len() as u64, "programs", Duration::from_millis(500));
    let rows = picks
        .iter()
        .enumerate()
        .map(|(k, &(split, i))| {
            let file = if split == Split::Train { train } else { val };
            let p = Program::from_record(i as u64, &file.record(i)).context("invalid program record")?;
            bar.set(k as u64 + 1, "");
            row(&p, file.motion(i), &env)
        })
        .collect::<anyhow::Result<Vec<Row>>>()?;
    bar.finish();

    let data = with_ext(&a.out, "gestures");
    write(&data, &rows, n_train)?;
    let (learner, mut learn) = super::super::encoder::learner_command(a.bin_dir.as_deref())?;
    let status = learn
        .args(["--device", "cpu", "probe-gesture", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(&a.out)
        .args(["--seed", &a.seed.to_string()])
        .status()
        .with_context(|| format!("starting {}", learner.display()))?;
    std::fs::remove_file(&data).with_context(|| format!("removing {}", data.display()))?;
    anyhow::ensure!(status.success(), "{} probe-gesture failed ({status})", learner.display());
    println!("probes in {} and {}", with_ext(&a.out, "md").display(), with_ext(&a.out, "json").display());
    Ok(())
}

fn view(dtype: Dtype, shape: Vec<usize>, bytes: &[u8]) -> TensorView<'_> {
    TensorView::new(dtype, shape, bytes).expect("sizes agree")
}

/// The probe's input file: `muscles` and `keypoints` (f16, as the policy reads them), `person`
/// and `target` (f32), `room` (i32), `held_out` (u8: 1 for the val programs).
fn write(path: &Path, rows: &[Row], n_train: usize) -> anyhow::Result<()> {
    let n = rows.len();
    let half = |f: fn(&Row) -> &[f32]| -> Vec<u8> {
        rows.iter().flat_map(|r| f(r).iter().flat_map(|v| f16::from_f32(*v).to_le_bytes())).collect()
    };
    let float = |f: fn(&Row) -> &[f32]| -> Vec<u8> {
        rows.iter().flat_map(|r| f(r).iter().flat_map(|v| v.to_le_bytes())).collect()
    };
    let muscles = half(|r| &r.muscles);
    let keypoints = half(|r| &r.keypoints);
    let person = float(|r| &r.person);
    let target = float(|r| &r.target);
    let room: Vec<u8> = rows.iter().flat_map(|r| r.room.to_le_bytes()).collect();
    let held: Vec<u8> = (0..n).map(|i| u8::from(i >= n_train)).collect();
    let tensors = [
        ("muscles", view(Dtype::F16, vec![n, FRAMES * MUSCLES], &muscles)),
        ("keypoints", view(Dtype::F16, vec![n, FRAMES * GESTURE_KEYPOINT_DIMS], &keypoints)),
        ("person", view(Dtype::F32, vec![n, 4], &person)),
        ("target", view(Dtype::F32, vec![n, 2], &target)),
        ("room", view(Dtype::I32, vec![n], &room)),
        ("held_out", view(Dtype::U8, vec![n], &held)),
    ];
    let bytes = safetensors::serialize(tensors, None).context("serialising the probe's inputs")?;
    farm::files::write_atomic(path, &bytes).with_context(|| format!("writing {}", path.display()))
}
