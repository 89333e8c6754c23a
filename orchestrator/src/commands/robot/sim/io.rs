//! What the simulator's robot publishes and hears, under the names the node resolves.

use ros2_client::dds::{Node, Publisher, Subscription};

use crate::commands::robot::args::Bus;
use crate::commands::robot::dds;
use crate::commands::robot::msgs::{
    CameraInfo, Clock, Decision, Gesture, IdsList, Image, Odometry, Skeleton2D, Text, Twist,
};
use crate::commands::robot::names::{self, Names, Resolved};

/// What the simulator's robot publishes and hears.
pub(super) struct Io {
    pub(super) node: Node,
    pub(super) colour: Publisher<Image>,
    pub(super) depth: Publisher<Image>,
    pub(super) info: Publisher<CameraInfo>,
    pub(super) odom: Publisher<Odometry>,
    pub(super) clock: Publisher<Clock>,
    pub(super) gesture: Publisher<Gesture>,
    pub(super) goal: Publisher<Text>,
    /// The tracker's bodies (REP-155): the person's id, and their keypoints.
    pub(super) tracked: Publisher<IdsList>,
    pub(super) skeleton: Publisher<Skeleton2D>,
    pub(super) cmd_vel: Subscription<Twist>,
    pub(super) decision: Subscription<Decision>,
    pub(super) person: Subscription<Gesture>,
    pub(super) names: Resolved,
}

impl Io {
    pub(super) fn open(bus: &Bus) -> anyhow::Result<Io> {
        let names = Names::new(&bus.namespace, names::NODE, &bus.remap)?;
        let r = Resolved::new(&names);
        let mut node = dds::node(bus.domain, names.namespace(), "gesthor_sim")?;
        let n = &mut node;
        Ok(Io {
            colour: dds::publisher(n, &r.colour, dds::reliable())?,
            depth: dds::publisher(n, &r.depth, dds::reliable())?,
            info: dds::publisher(n, &r.info, dds::reliable())?,
            odom: dds::publisher(n, &r.odom, dds::reliable())?,
            clock: dds::publisher(n, &r.clock, dds::reliable())?,
            gesture: dds::publisher(n, &r.gesture, dds::reliable())?,
            goal: dds::publisher(n, &r.goal, dds::reliable())?,
            tracked: dds::publisher(n, &r.tracked, dds::reliable())?,
            skeleton: dds::publisher(n, &r.skeleton(super::tracker::BODY), dds::reliable())?,
            cmd_vel: dds::subscription(n, &r.cmd_vel, dds::reliable())?,
            decision: dds::subscription(n, &r.decision, dds::reliable())?,
            person: dds::subscription(n, &r.person, dds::reliable())?,
            names: r,
            node,
        })
    }
}
