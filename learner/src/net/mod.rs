//! The policy network of §4.3.3 and the agent that acts with it, lowest layer first:
//!
//! - [`spec`]: what the network looks like for a run ([`spec::NetSpec`]);
//! - [`pth`]: PyTorch's `torch.save` state dicts, read without Python;
//! - [`resnet`]: ResNet-18 up to conv5 and the torchvision weights the user supplies;
//! - [`layers`]: the building blocks (visual encoders, the frozen trunk, the MLPs);
//! - `gesture_net`: the gesture network, §4.3.3's flat layer alone or beside one shared per frame;
//! - `gesture_memo`: acting's gesture features, kept per env from one step to the next;
//! - `stretches`: PPO's GRU over whole sequences, each env cut at its own episode starts, one call;
//! - [`network`]: the layers wired together ([`network::PolicyNet`]);
//! - [`agent`]: the acting agent ([`agent::Agent`]): the network, its variables, each env's memory.

pub mod agent;
pub(crate) mod gesture_memo;
pub(crate) mod gesture_net;
pub mod layers;
pub mod network;
pub mod pth;
pub mod resnet;
pub mod spec;
pub(crate) mod stretches;
