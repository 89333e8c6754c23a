//! ROS names as ROS users expect them: relative names resolve in the node's namespace, `~/x`
//! in the node's own, and `--remap from:=to` replaces a resolved name.

/// How the node's names resolve.
#[derive(Clone, Debug)]
pub struct Names {
    namespace: String,
    node: String,
    /// Resolved `from` → resolved `to`.
    remaps: Vec<(String, String)>,
}

impl Names {
    /// `namespace` (`locobot` or `/locobot`; empty: the root) and `remaps` as `from:=to`.
    pub fn new(namespace: &str, node: &str, remaps: &[String]) -> anyhow::Result<Names> {
        let ns = format!("/{}", namespace.trim_matches('/'));
        let mut n = Names { namespace: ns, node: node.to_string(), remaps: Vec::new() };
        for r in remaps {
            let (from, to) = r
                .split_once(":=")
                .ok_or_else(|| anyhow::anyhow!("--remap `{r}`: FROM:=TO expected (cmd_vel:=mobile_base/cmd_vel)"))?;
            anyhow::ensure!(!from.is_empty() && !to.is_empty(), "--remap `{r}`: a name on each side of := expected");
            let pair = (n.plain(from), n.plain(to));
            n.remaps.push(pair);
        }
        Ok(n)
    }

    pub fn namespace(&self) -> &str {
        &self.namespace
    }

    /// The absolute name, before remapping.
    fn plain(&self, name: &str) -> String {
        let ns = self.namespace.trim_end_matches('/');
        if let Some(private) = name.strip_prefix("~/") {
            format!("{ns}/{}/{private}", self.node)
        } else if name.starts_with('/') {
            name.to_string()
        } else {
            format!("{ns}/{name}")
        }
    }

    /// The absolute name of a topic the node uses, after remapping.
    pub fn resolve(&self, name: &str) -> String {
        let plain = self.plain(name);
        self.remaps.iter().find(|(from, _)| *from == plain).map_or(plain, |(_, to)| to.clone())
    }
}

/// The topics of the node and of the simulator's robot, by their ROS defaults (a LoCoBot's).
#[derive(Clone, Debug)]
pub struct Resolved {
    pub colour: String,
    pub depth: String,
    pub info: String,
    pub odom: String,
    pub cmd_vel: String,
    pub goal: String,
    pub decision: String,
    pub gesture: String,
    /// The person as the node's camera read them (`--gesture camera`).
    pub person: String,
    pub clock: String,
    /// REP-155's bodies (`--gesture skeleton`): those a tracker follows, and where each one's
    /// topics are (`BODIES/<id>/skeleton2d`; remapping `/humans/bodies` moves them all).
    pub tracked: String,
    pub bodies: String,
}

/// The node's name: its goal and decision topics are its own (`~/goal`).
pub const NODE: &str = "gesthor_robot";

impl Resolved {
    pub fn new(names: &Names) -> Resolved {
        Resolved {
            colour: names.resolve("camera/color/image_raw"),
            depth: names.resolve("camera/aligned_depth_to_color/image_raw"),
            info: names.resolve("camera/color/camera_info"),
            odom: names.resolve("odom"),
            cmd_vel: names.resolve("cmd_vel"),
            goal: names.resolve("~/goal"),
            decision: names.resolve("~/decision"),
            gesture: names.resolve("gesthor/gesture"),
            person: names.resolve("~/person"),
            clock: names.resolve("/clock"),
            tracked: names.resolve("/humans/bodies/tracked"),
            bodies: names.resolve("/humans/bodies"),
        }
    }

    /// A body's keypoints (REP-155).
    pub fn skeleton(&self, id: &str) -> String {
        format!("{}/{id}/skeleton2d", self.bodies)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_resolve_as_in_ros() {
        let n = Names::new("", "gesthor_robot", &[]).unwrap();
        assert_eq!(n.resolve("odom"), "/odom");
        assert_eq!(n.resolve("~/decision"), "/gesthor_robot/decision");
        let n =
            Names::new("locobot", "gesthor_robot", &["cmd_vel:=mobile_base/cmd_vel".into(), "odom:=/odom_raw".into()])
                .unwrap();
        assert_eq!(n.resolve("camera/color/image_raw"), "/locobot/camera/color/image_raw");
        assert_eq!(n.resolve("cmd_vel"), "/locobot/mobile_base/cmd_vel");
        assert_eq!(n.resolve("odom"), "/odom_raw");
        assert_eq!(n.resolve("~/goal"), "/locobot/gesthor_robot/goal");
        assert!(Names::new("", "n", &["cmd_vel=x".into()]).unwrap_err().to_string().contains("FROM:=TO"));
    }
}
