//! `orchestrator follow`: a trained agent answers a person's own gesture. The gesture (a motion
//! CSV, as `gesture capture` writes it) takes the place of a dataset program's, whose person and
//! robot may be moved (`--person`, `--robot`); the checkpoint
//! runs that program as `eval` does (actions sampled from the policy, seeded; unlimited stops;
//! the intervention gestures shown whenever the agent faces away, for the methods that see
//! them), and `follow.gif` shows the robot's view beside the top-down map of its path. SR and SPL at the first stop, where it
//! stopped and how far from the target go to the terminal and `result.json`.
//!
//! ```text
//! OUT/dataset/    the one program, its rooms and intervention gestures read from --dataset
//! OUT/eval/       the evaluation (tables, episodes, trajectory)
//! OUT/follow.gif  the robot's view (the band: gesture perceived) beside the map
//! OUT/result.json what the terminal says
//! ```

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use serde::Serialize;

use farm::config::RunConfig;
use farm::metrics::{EpisodeResult, spl};
use worker::dataset::build::with_poses;
use worker::dataset::{Dataset, Verify, write_subset};
use worker::gesture::motion::read_csv;
use worker::program::Program;
use worker::scene::Split;

use super::eval::{EvalArgs, read_episodes};
use crate::report::trajectory;

#[derive(Args, Debug)]
pub struct FollowArgs {
    /// A checkpoint file, a run directory (its newest complete checkpoint), or a shipped model
    /// (`models/both`).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// The program the gesture was recorded into (SPLIT:INDEX): its room, target, person and
    /// robot start.
    #[arg(long)]
    pub program: String,
    /// The gesture: a motion CSV (`gesture capture` writes OUT/motions/NAME.csv); default: the
    /// program's own.
    #[arg(long)]
    pub motion: Option<PathBuf>,
    /// Move the person in the program's room: x, z (metres) and yaw (degrees; they must face
    /// the target).
    #[arg(long, num_args = 3, value_names = ["X", "Z", "YAW"], allow_hyphen_values = true)]
    pub person: Option<Vec<f32>>,
    /// Move the robot's start: x, z (metres; taken to the nearest 0.25 m grid point) and yaw.
    #[arg(long, num_args = 3, value_names = ["X", "Z", "YAW"], allow_hyphen_values = true)]
    pub robot: Option<Vec<f32>>,
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
}

/// What the agent did.
#[derive(Debug, Serialize)]
pub struct FollowResult {
    pub program: String,
    pub motion: Option<PathBuf>,
    /// Success and SPL when the episode ends at the first stop.
    pub success_first_stop: bool,
    pub spl_first_stop: f64,
    /// Step of the first stop and the robot's distance from the target there (None: never stopped).
    pub first_stop: Option<(u32, f32)>,
    /// With unlimited stops (within the step limit).
    pub success: bool,
    pub steps: u32,
    pub gif: PathBuf,
}

pub fn run(a: FollowArgs) -> anyhow::Result<()> {
    let (split, p, one) = one_program(&a)?;
    let ev = a.out.join("eval");
    evaluate(&a, split, &one, &ev)?;
    let result = follow_result(&a, &ev)?;
    let outcome = match (result.success_first_stop, result.success) {
        (true, _) => "success at the first stop".to_string(),
        (false, true) => "success after more stops".to_string(),
        (false, false) => "failure".to_string(),
    };
    picture(&a, split, &one, &ev, &format!("{} → {}: {outcome}", a.program, p.target.name()), &result.gif)?;
    farm::files::write_atomic(&a.out.join("result.json"), serde_json::to_string_pretty(&result)?.as_bytes())?;
    let stop = match result.first_stop {
        Some((step, d)) => format!("first stop at step {step}, {d:.2} m from the target"),
        None => "never stopped".into(),
    };
    println!(
        "{} ({}): {outcome}; {stop}; SR at the first stop {}, SPL {:.2}; {} steps; {}",
        a.program,
        a.motion.as_ref().map_or("its own gesture".into(), |m| m.display().to_string()),
        result.success_first_stop as u8,
        result.spl_first_stop,
        result.steps,
        result.gif.display()
    );
    Ok(())
}

/// The program asked for, with the person and robot where asked and the gesture given, written
/// as a dataset of its own (OUT/dataset): its split, the program and the dataset's folder.
fn one_program(a: &FollowArgs) -> anyhow::Result<(Split, Program, PathBuf)> {
    let (split, i) = super::program::parse_ref(&a.program)
        .with_context(|| format!("--program: `{}` is not SPLIT:INDEX (e.g. val:17)", a.program))?;
    // the person's gesture first: the file they named is the likelier mistake
    let given = a.motion.as_deref().map(read_csv).transpose()?;
    let ds = Dataset::open(&a.dataset, Verify::Quick)?;
    let (p, own) = super::program::dataset_program(&ds, split, i)?;
    let p = match (&a.person, &a.robot) {
        (None, None) => p,
        (person, robot) => {
            let scene = ds.scene(p.scene_id())?;
            let person = person.as_ref().map(|v| (nalgebra::Point2::new(v[0], v[1]), v[2]));
            let robot = robot.as_ref().map(|v| worker::robot::RobotPose { x: v[0], z: v[1], yaw: v[2] });
            with_poses(&scene, &p, person, robot, ds.manifest.build.success_distance)
                .map_err(|e| anyhow::anyhow!("--person/--robot in {} ({}): {e}", a.program, p.scene))?
        }
    };
    let motion = match given {
        Some(m) => m.as_flat().to_vec(),
        None => own.as_flat().to_vec(),
    };
    let one = a.out.join("dataset");
    write_subset(&one, &ds, split, &[(p.clone(), motion)]).with_context(|| format!("writing {}", one.display()))?;

    Ok((split, p, one))
}

/// The checkpoint's one episode on the one program (OUT/eval).
fn evaluate(a: &FollowArgs, split: Split, one: &Path, ev: &Path) -> anyhow::Result<()> {
    super::eval::run(EvalArgs {
        checkpoint: Some(a.checkpoint.clone()),
        expert: false,
        greedy: false,
        scenes: vec![],
        split: split.name().into(),
        workers: 1,
        config: None,
        dataset: Some(one.to_path_buf()),
        max_programs: None,
        modes: vec!["normal".into()],
        dts_threshold: 1.5,
        out: Some(ev.to_path_buf()),
        label: None,
        trajectories: 0,
        set: vec![],
        compare: vec![],
    })?;
    Ok(())
}

/// What the episode did.
fn follow_result(a: &FollowArgs, ev: &Path) -> anyhow::Result<FollowResult> {
    let episodes: Vec<EpisodeResult> = read_episodes(&ev.join("normal/episodes.jsonl"))?;
    let e = episodes.first().with_context(|| format!("{}: no episode", ev.display()))?;
    let first = e.stops.first();
    Ok(FollowResult {
        program: a.program.clone(),
        motion: a.motion.clone(),
        success_first_stop: first.is_some_and(|s| s.success),
        spl_first_stop: first.filter(|s| s.success).map_or(0.0, |s| spl(e.shortest_path as f64, s.path_length as f64)),
        first_stop: first.map(|s| (s.step, s.distance)),
        success: e.success,
        steps: e.steps,
        gif: a.out.join("follow.gif"),
    })
}

/// The robot's view along the episode beside the map of its path, as a GIF.
fn picture(a: &FollowArgs, split: Split, one: &Path, ev: &Path, title: &str, gif: &Path) -> anyhow::Result<()> {
    let (_, run_dir) = super::eval::locate(&a.checkpoint)?;
    let mut cfg = RunConfig::load(&run_dir.join("config.toml"))?;
    cfg.run.split = split;
    let trajs = trajectory::read(&ev.join("normal/trajectories.jsonl"))?;
    let t = trajs.first().with_context(|| format!("{}: no trajectory", ev.display()))?;
    trajectory::write_program_gif(&cfg, one, split, t, title, gif)
}
