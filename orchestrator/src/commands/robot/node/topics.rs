//! The node's topics: what it subscribes to and publishes, by their resolved names.

use ros2_client::dds::{Node, Publisher, Subscription};

use crate::commands::robot::args::NodeArgs;
use crate::commands::robot::dds;
use crate::commands::robot::msgs::{
    CameraInfo, Clock, Decision, Gesture, Header, Image, Odometry, Text, Twist, TwistStamped,
};
use crate::commands::robot::names::{self, Names, Resolved};

/// The node's topics, resolved.
pub struct Io {
    pub node: Node,
    pub colour: Subscription<Image>,
    pub depth: Subscription<Image>,
    pub info: Subscription<CameraInfo>,
    pub odom: Subscription<Odometry>,
    pub goal: Subscription<Text>,
    pub gesture: Subscription<Gesture>,
    pub clock: Option<Subscription<Clock>>,
    pub cmd: Cmd,
    pub decision: Publisher<Decision>,
    pub person: Publisher<Gesture>,
    pub names: Resolved,
}

/// How commands go out: Twist, or TwistStamped (`--stamped`).
pub enum Cmd {
    Plain(Publisher<Twist>),
    Stamped(Publisher<TwistStamped>),
}

impl Io {
    pub fn open(args: &NodeArgs) -> anyhow::Result<Io> {
        let names = Names::new(&args.bus.namespace, names::NODE, &args.bus.remap)?;
        let r = Resolved::new(&names);
        let mut node = dds::node(args.bus.domain, names.namespace(), names::NODE)?;
        let n = &mut node;
        let cmd = match args.stamped {
            true => Cmd::Stamped(dds::publisher(n, &r.cmd_vel, dds::reliable())?),
            false => Cmd::Plain(dds::publisher(n, &r.cmd_vel, dds::reliable())?),
        };
        Ok(Io {
            colour: dds::subscription(n, &r.colour, dds::sensor())?,
            depth: dds::subscription(n, &r.depth, dds::sensor())?,
            info: dds::subscription(n, &r.info, dds::sensor())?,
            odom: dds::subscription(n, &r.odom, dds::sensor())?,
            goal: dds::subscription(n, &r.goal, dds::reliable())?,
            gesture: dds::subscription(n, &r.gesture, dds::sensor())?,
            clock: match args.bus.use_sim_time {
                true => Some(dds::subscription(n, &r.clock, dds::sensor())?),
                false => None,
            },
            decision: dds::publisher(n, &r.decision, dds::reliable())?,
            person: dds::publisher(n, &r.person, dds::reliable())?,
            cmd,
            names: r,
            node,
        })
    }
}

impl Cmd {
    /// A twist of `v` m/s ahead and `w` rad/s to the left, stamped `now` (ROS time) where the
    /// base takes TwistStamped.
    pub fn publish(&self, v: f64, w: f64, now: f64) -> Result<(), String> {
        let twist = Twist::planar(v, w);
        match self {
            Cmd::Plain(p) => p.publish(twist).map_err(|e| format!("{e:?}")),
            Cmd::Stamped(p) => {
                let header = Header::new(dds::time(now), "base_link");
                p.publish(TwistStamped { header, twist }).map_err(|e| format!("{e:?}"))
            }
        }
    }
}
