//! The node on the DDS bus: a ROS 2 participant in a domain, and its topics with the QoS a ROS
//! 2 peer expects (sensor streams best effort, commands and decisions reliable).

use anyhow::Context as _;
use ros2_client::dds::rustdds::Topic;
use ros2_client::dds::{Context, ContextOptions, Node, Publisher, Subscription};
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{Message, Name, NodeName, NodeOptions, QosProfile};
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::msgs::Typed;

/// Sensor streams: the newest few, none resent (a reader of either kind matches).
pub fn sensor() -> QosProfile {
    QosProfile::publisher_default()
        .reliability_best_effort()
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 5 })
}

/// Commands, goals and decisions: none lost.
pub fn reliable() -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 10 })
}

/// A ROS 2 node in `domain` (ROS_DOMAIN_ID).
pub fn node(domain: u16, namespace: &str, name: &str) -> anyhow::Result<Node> {
    let ctx = Context::with_options(ContextOptions::new().domain_id(domain))
        .with_context(|| format!("joining DDS domain {domain}"))?;
    let node_name = NodeName::new(namespace, name).map_err(|e| anyhow::anyhow!("node name {namespace}/{name}: {e}"))?;
    ctx.new_node(node_name, NodeOptions::new()).with_context(|| format!("starting ROS 2 node {name}"))
}

fn topic<M: Typed>(node: &mut Node, name: &str, qos: &QosProfile) -> anyhow::Result<Topic> {
    let n = Name::parse(name).map_err(|e| anyhow::anyhow!("topic {name}: {e}"))?;
    node.create_topic(&n, M::type_name(), qos).with_context(|| format!("topic {name}"))
}

pub fn publisher<M: Typed + Message + Serialize>(
    node: &mut Node,
    name: &str,
    qos: QosProfile,
) -> anyhow::Result<Publisher<M>> {
    let t = topic::<M>(node, name, &qos)?;
    node.create_publisher(&t, Some(qos)).with_context(|| format!("publishing {name}"))
}

pub fn subscription<M: Typed + Message + DeserializeOwned + 'static>(
    node: &mut Node,
    name: &str,
    qos: QosProfile,
) -> anyhow::Result<Subscription<M>> {
    let t = topic::<M>(node, name, &qos)?;
    node.create_subscription(&t, Some(qos)).with_context(|| format!("subscribing to {name}"))
}

/// Every message waiting on `sub`, oldest first; a message that does not decode is dropped
/// (its writer speaks another type under the same name) and reported once by the caller.
pub fn drain<M: Message + DeserializeOwned + 'static>(sub: &Subscription<M>) -> (Vec<M>, Option<String>) {
    let (mut out, mut err) = (Vec::new(), None);
    loop {
        match sub.take() {
            Ok(Some((m, _))) => out.push(m),
            Ok(None) => return (out, err),
            Err(e) => err = Some(format!("{e:?}")),
        }
    }
}

/// The one line that says a topic carried a message of another type (a writer of another type
/// under the same name), `e` the decoder's complaint.
pub fn not_of_its_type(topic: &str, e: &str) -> String {
    format!("{topic}: a message that is not of its type ({e})")
}

/// ROS time in seconds.
pub fn seconds(t: ros2_client::builtin_interfaces::Time) -> f64 {
    t.to_nanos() as f64 * 1e-9
}

pub fn time(seconds: f64) -> ros2_client::builtin_interfaces::Time {
    ros2_client::builtin_interfaces::Time::from_nanos((seconds * 1e9).round() as i64)
}
