//! The join protocol: a worker host asks the run's learner host for slots (`gesthor/join`) with
//! a proof that it knows the run's secret, and the grant proves the same of the learner. The
//! learner's side answers in `learner_bridge`.

use std::time::Duration;

use anyhow::Context;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use zenoh::Wait;

/// The key a worker host asks to join under.
pub(super) const JOIN_KEY: &str = "gesthor/join";
/// How long a host waits for the learner's answer to a join.
const JOIN_TIMEOUT: Duration = Duration::from_secs(10);

/// SHA-256 of the secret, who speaks, the run id and the nonce, in hex.
pub(super) fn proof(secret: &str, role: &str, run_id: &str, nonce: &str) -> String {
    let mut h = Sha256::new();
    for part in [secret, role, run_id, nonce] {
        h.update((part.len() as u64).to_le_bytes());
        h.update(part.as_bytes());
    }
    farm::files::hex(&h.finalize())
}

/// `bytes` random bytes from the kernel, in hex (secrets, nonces, grant tokens).
pub fn random_hex(bytes: usize) -> String {
    let mut b = vec![0u8; bytes];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut b))
        .expect("/dev/urandom is readable");
    farm::files::hex(&b)
}

/// What a worker host asks.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct JoinRequest {
    pub run_id: String,
    pub workers: u32,
    pub host: String,
    pub nonce: String,
    pub proof: String,
}

/// What the learner's host grants.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct JoinGrant {
    pub first_slot: u32,
    pub first_generation: u32,
    pub token: u64,
    /// The run's effective configuration (the host's workers read it).
    pub config_toml: String,
    /// SHA-256 of the dataset's manifest: the host's copy must be the same dataset.
    pub manifest_digest: String,
    pub proof: String,
}

/// Asks the run's learner host to take `workers` workers; the grant, or the refusal as an error.
pub fn join(
    session: &zenoh::Session,
    run_id: &str,
    secret: &str,
    workers: u32,
    host: &str,
) -> anyhow::Result<JoinGrant> {
    let nonce = random_hex(16);
    let req = JoinRequest {
        run_id: run_id.into(),
        workers,
        host: host.into(),
        proof: proof(secret, "host", run_id, &nonce),
        nonce: nonce.clone(),
    };
    let replies = session
        .get(JOIN_KEY)
        .payload(serde_json::to_vec(&req)?)
        .timeout(JOIN_TIMEOUT)
        .wait()
        .map_err(|e| anyhow::anyhow!("asking to join: {e}"))?;
    let reply = replies
        .recv_timeout(JOIN_TIMEOUT + Duration::from_secs(1))
        .ok()
        .flatten()
        .with_context(|| format!("no learner answered within {} s", JOIN_TIMEOUT.as_secs()))?;
    match reply.result() {
        Ok(sample) => {
            let g: JoinGrant =
                serde_json::from_slice(&sample.payload().to_bytes()).context("the learner's grant does not parse")?;
            anyhow::ensure!(
                g.proof == proof(secret, "learner", run_id, &nonce),
                "the learner that answered does not know this run's secret"
            );
            Ok(g)
        }
        Err(e) => anyhow::bail!("the learner refused: {}", String::from_utf8_lossy(&e.payload().to_bytes())),
    }
}
