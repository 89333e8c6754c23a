//! More than one machine: worker hosts join a run over Zenoh.
//!
//! The learner's host (`up --listen ENDPOINT --remote-workers R`) reserves R learner slots after
//! its local workers and runs a [`LearnerBridge`]: for each remote slot it stands in for a worker
//! towards the learner (an iceoryx2 publisher of `obs/<slot>` in the run's shared memory, a
//! subscriber of `act/<slot>`), so the learner reads remote frames exactly as local ones. A
//! worker host (`orchestrator workers --connect ENDPOINT`) asks to join (`gesthor/join`), is
//! granted a range of slots, the run's config and a generation base above any earlier process
//! in those slots, starts its workers as those slots in its own shared-memory domain, and runs a
//! [`HostBridge`] that stands in for the learner towards them. Between the two bridges:
//!
//! - `gesthor/<run>/obs/<slot>`: an observation (codec, grant token, header, payload; LZ4 or
//!   Zstandard if asked), host → learner;
//! - `gesthor/<run>/act/<slot>`: an action message (token, message), learner → host;
//! - liveliness tokens `gesthor/<run>/learner` and `gesthor/<run>/host/<token>`: a vanished
//!   host frees its slots (the learner sees them as missing workers, one batch timeout each
//!   round), a vanished learner ends the host's workers.
//!
//! Links are TLS with a certificate on each side (`certs`): the learner trusts the hosts whose
//! bundles were issued for the run and not revoked, hosts trust the run's learner, and Zenoh's
//! access control (`access`) lets hosts send only observations, joins and their presence. A
//! peer without such a certificate does not get past the handshake. Plain TCP only with
//! `--insecure`. Issuing or revoking a host makes the learner reopen its listener with the new
//! trust (`gesthor/<run>/reopen` tells the hosts to wait for it). On top, a join proves
//! knowledge of the run's secret (SHA-256 over the secret, the run id and a nonce), and so does
//! the grant; messages carry the grant's token: a host whose slots were given to another is
//! ignored.
//!
//! By concept: `session` (the Zenoh peer), `certs` (who may join), `access` (what each may
//! send), `wire` (keys and bytes), `join` (asking for slots and proving the secret), `bridge`
//! (the thread, wait set and doorbell both bridges use), and the two sides, `learner_bridge`
//! and `host_bridge`.

mod access;
mod bridge;
pub mod certs;
mod host_bridge;
mod join;
mod learner_bridge;
pub mod refusals;
mod session;
mod wire;

pub use bridge::BridgeCounts;
pub use host_bridge::{HostBridge, HostOptions};
pub use join::{JoinGrant, JoinRequest, join, random_hex};
pub use learner_bridge::{LearnerBridge, ListenOptions};
pub use session::{DEFAULT_PORT, Security, check_endpoint, config, hostname, session, short_slices};
pub use wire::{Codec, decode_obs, encode_obs};
