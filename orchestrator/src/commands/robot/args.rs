//! The command line the node and the simulator's robot share: where they are on the bus, and
//! the node's own limits.

use std::path::PathBuf;

use clap::Args;

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
    /// Where the person's gesture comes from: `topic` (gesthor/gesture: a tracker, or the
    /// simulator's truth) or `camera` (the landmark model on the robot's colour frames).
    #[arg(long, default_value = "topic", value_parser = ["topic", "camera"])]
    pub gesture: String,
    /// With `--gesture camera`: how long the person's gesture is watched at an episode's start
    /// (s, ROS time; GOND's gestures last 3.3 s).
    #[arg(long, default_value_t = 3.5)]
    pub capture_seconds: f64,
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
