//! `orchestrator robot`: the trained robot on ROS 2 topics. The node (`node`) reads a real
//! robot's camera, odometry and the person's gesture and drives its base; `robot sim` (`sim`)
//! is GesTHOR published as such a robot, so the node can be run and judged closed-loop. Both
//! speak DDS directly (ros2-client on RustDDS): no ROS installation is needed, and any ROS 2
//! node of Humble or later on the same domain sees their topics.
//!
//! ```text
//!   camera/color/image_raw ──────────────┐
//!   camera/aligned_depth_to_color/… ─────┤                       ┌─► cmd_vel
//!   camera/color/camera_info ────────────┼─► orchestrator robot ─┤
//!   odom ────────────────────────────────┤   (learner act)       ├─► gesthor_robot/decision
//!   gesthor/gesture ─────────────────────┤                       └─► gesthor_robot/person
//!   gesthor_robot/goal ("Television") ───┘
//! ```

/// A line the operator must see (the node's state changes), whatever RUST_LOG says.
macro_rules! say {
    ($($t:tt)*) => { eprintln!("robot: {}", format!($($t)*)) };
}

pub mod args;
pub mod camera;
pub mod dds;
pub mod drive;
pub mod msgs;
pub mod names;
pub mod node;
pub mod observation;
pub mod person;
pub mod reading;
pub mod sim;

use clap::{Args, Subcommand};

pub use args::{Bus, NodeArgs, SimArgs};

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct RobotArgs {
    #[command(subcommand)]
    pub cmd: Option<RobotCmd>,
    #[command(flatten)]
    pub node: NodeArgs,
}

#[derive(Subcommand, Debug)]
pub enum RobotCmd {
    /// GesTHOR as a ROS 2 robot: a program's room and person, a 640×480 RGB-D camera and
    /// odometry published, `cmd_vel` integrated with the simulator's collisions, each episode
    /// judged by the task's rules and recorded.
    Sim(SimArgs),
}

pub fn run(a: RobotArgs) -> anyhow::Result<()> {
    match a.cmd {
        Some(RobotCmd::Sim(s)) => sim::run(s),
        None => node::run(a.node),
    }
}
