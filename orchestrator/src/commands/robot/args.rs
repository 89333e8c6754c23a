//! The command lines of the node and of the simulator's robot: where they are on the bus, the
//! node's own limits, the simulator's programs and camera.

use std::path::PathBuf;

use anyhow::Context as _;
use clap::Args;

use worker::dataset::Dataset;
use worker::scene::Split;

/// Where the node is on the bus: shared by the node and the simulator's robot.
#[derive(Args, Debug, Clone)]
pub struct Bus {
    /// The DDS domain (default: $ROS_DOMAIN_ID, else 0).
    #[arg(long, default_value_t = ros_domain_id())]
    pub domain: u16,
    /// The namespace the robot's topics resolve in (`locobot` for an Interbotix LoCoBot).
    #[arg(long, default_value = "")]
    pub namespace: String,
    /// Remap a topic, as `ros2 run … --ros-args -r FROM:=TO` (repeat it):
    /// `--remap cmd_vel:=mobile_base/cmd_vel`.
    #[arg(long, value_name = "FROM:=TO")]
    pub remap: Vec<String>,
    /// Time is the simulator's `/clock` (as ROS's use_sim_time).
    #[arg(long)]
    pub use_sim_time: bool,
}

#[derive(Args, Debug, Clone)]
pub struct NodeArgs {
    /// A shipped model (`models/both`), a run directory or a checkpoint file.
    #[arg(long, default_value = "models/both")]
    pub checkpoint: PathBuf,
    #[command(flatten)]
    pub bus: Bus,
    /// Start an episode at once, to this target category (`Television`); otherwise each goal on
    /// `~/goal` (std_msgs/String) starts one.
    #[arg(long)]
    pub target: Option<String>,
    /// Top forward speed (m/s) and turn rate (rad/s): a LoCoBot's by default.
    #[arg(long, default_value_t = 0.2)]
    pub max_speed: f64,
    #[arg(long, default_value_t = 0.5)]
    pub max_turn_rate: f64,
    /// A move that makes no progress for this long (s) was blocked: the next step is decided.
    #[arg(long, default_value_t = 1.5)]
    pub stall_seconds: f64,
    /// A camera frame older than this (s, ROS time) is too old to act on.
    #[arg(long, default_value_t = 0.5)]
    pub max_age: f64,
    /// A topic silent this long (s, wall clock) is lost: odometry, the camera.
    #[arg(long, default_value_t = 1.0)]
    pub input_timeout: f64,
    /// Where the person's gesture comes from: `topic` (gesthor/gesture: the simulator's truth,
    /// or a node that reads people), `camera` (the landmark model on the robot's colour frames)
    /// or `skeleton` (REP-155's /humans/bodies/<id>/skeleton2d from a body tracker, measured by
    /// the aligned depth).
    #[arg(long, default_value = "topic", value_parser = ["topic", "camera", "skeleton"])]
    pub gesture: String,
    /// With `--gesture camera` or `skeleton`: how long the person's gesture is watched at an
    /// episode's start (s, ROS time): two of GOND's 3.3 s gestures, so that one is seen whole
    /// whenever the person began it.
    #[arg(long, default_value_t = 7.0)]
    pub capture_seconds: f64,
    /// With `--gesture camera`: frames a second the landmark model reads between captures, for
    /// a wave (0: every frame). A capture reads every frame.
    #[arg(long, default_value_t = 5.0)]
    pub wave_rate: f64,
    /// Take the policy's most likely action at every step instead of sampling it (as `eval
    /// --greedy`: the same observations then give the same decisions).
    #[arg(long)]
    pub greedy: bool,
    /// Publish geometry_msgs/TwistStamped on cmd_vel (ROS 2 Jazzy bases) instead of Twist.
    #[arg(long)]
    pub stamped: bool,
}

fn ros_domain_id() -> u16 {
    std::env::var("ROS_DOMAIN_ID").ok().and_then(|v| v.parse().ok()).unwrap_or(0)
}

#[derive(Args, Debug)]
pub struct SimArgs {
    /// The model (or run, or checkpoint) whose run config sets the task's rules, the camera's
    /// vertical field of view and which gestures the person shows.
    #[arg(long, default_value = "models/both")]
    pub checkpoint: PathBuf,
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    /// The programs: SPLIT:FIRST-LAST, or SPLIT:INDEX.
    #[arg(long, default_value = "val:0-9")]
    pub programs: String,
    /// Instead of a range: this many programs of the split, spread as `eval --max-programs`
    /// spreads them (the same programs `eval` runs).
    #[arg(long, value_name = "N")]
    pub spread: Option<usize>,
    /// The camera's image size; its vertical field of view is the policy's.
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Odometry and physics ticks a second, and camera frames a second (simulated time).
    #[arg(long, default_value_t = 30.0)]
    pub rate: f64,
    #[arg(long, default_value_t = 5.0)]
    pub camera_rate: f64,
    /// How the person's gesture moves: `steps` (3 frames a decision, as in training and `eval`)
    /// or `time` (30 frames a second, as a person would: for `--gesture camera`).
    #[arg(long, default_value = "steps", value_parser = ["steps", "time"])]
    pub animate: String,
    /// Pace simulated time to the wall clock.
    #[arg(long)]
    pub realtime: bool,
    /// Draw the first N episodes: `episode-NNN/episode.gif`, the robot's view beside its map.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub gifs: usize,
    /// How long to wait (s, wall clock) for the node to appear, and for it to answer a tick.
    #[arg(long, default_value_t = 60.0)]
    pub wait: f64,
    #[command(flatten)]
    pub bus: Bus,
    /// Where the episodes are recorded (a folder each), with summary.json. A run of the same
    /// programs that stopped goes on from its first unfinished episode.
    #[arg(long, default_value = "runs/robot-sim")]
    pub out: PathBuf,
}

/// The programs `--programs`/`--spread` name, in their split.
pub fn programs(a: &SimArgs, ds: &Dataset) -> anyhow::Result<(Split, Vec<u64>)> {
    let bad = || format!("--programs `{}`: SPLIT:FIRST-LAST or SPLIT:INDEX expected (val:0-199)", a.programs);
    let (split, range) = a.programs.split_once(':').with_context(bad)?;
    let split = Split::from_name(split).with_context(bad)?;
    let total = ds.index(split)?.len();
    let list: Vec<u64> = match (a.spread, range.split_once('-')) {
        (Some(n), _) => crate::commands::eval::choose_programs(total, Some(n)),
        (None, Some((f, l))) => (f.parse().with_context(bad)?..=l.parse().with_context(bad)?).collect(),
        (None, None) => vec![range.parse().with_context(bad)?],
    };
    anyhow::ensure!(
        list.iter().all(|&i| (i as usize) < total),
        "--programs `{}`: {} holds {total} programs of {}",
        a.programs,
        ds.dir.display(),
        split.name()
    );
    Ok((split, list))
}
