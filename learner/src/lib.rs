//! The learner of GesTHOR-RS: the policy server of the rollout farm (`serve`, over `transport`)
//! and the policies it serves (`policy`).

pub mod batch;
pub mod policy;
pub mod serve;
pub mod transport;
