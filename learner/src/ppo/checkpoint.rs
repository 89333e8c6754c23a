//! Checkpoints: one safetensors file holding the network's variables (`model.<name>`), Adam's
//! state (`adam.exp_avg.<name>`, `adam.exp_avg_sq.<name>`), and in the metadata the update and
//! frame counts, Adam's step, the random streams, the config and its hash, and a SHA-256 of
//! every tensor, so a damaged file is refused instead of half-loaded.
//!
//! Files are written atomically (temporary file, fsync, rename): a reader — evaluation running
//! beside training — sees only complete checkpoints. They are named `ckpt-<update>.safetensors`
//! in `<run>/checkpoints/`.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use farm::config::{GestureNetwork, RunConfig};
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::SeedableRng;
use safetensors::{Dtype, SafeTensors, tensor::TensorView};
use sha2::{Digest, Sha256};
use tch::{Device, Kind, Tensor};

use crate::net::agent::{Agent, AgentError};
use crate::net::spec::NetSpec;
use crate::ppo::trainer::Trainer;

use farm::checkpoints::{FORMAT, digest};

/// A checkpoint that cannot be used: the file, and one reason.
#[derive(Debug, thiserror::Error)]
#[error("checkpoint {file}: {reason}")]
pub struct CheckpointError {
    pub file: String,
    pub reason: String,
}

/// Why a network could not be restored from a checkpoint: it cannot be built for this config, or
/// the file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum RestoreError {
    #[error(transparent)]
    Build(#[from] AgentError),
    #[error(transparent)]
    File(#[from] CheckpointError),
}

fn error(path: &Path, reason: impl Into<String>) -> CheckpointError {
    CheckpointError { file: path.display().to_string(), reason: reason.into() }
}

/// Hash of what decides the network's shapes and inputs (method, encoder and whether it is
/// frozen, inputs, frame size, widths). A checkpoint loads only into a network with the same hash.
pub fn config_hash(cfg: &RunConfig) -> String {
    let s = NetSpec::from_config(cfg);
    let key = format!(
        "method={:?};encoder={:?};frozen={};rgb={};depth={};gesture={};semantic={};pose={};hw={}x{};hidden={};gru={}",
        s.method,
        s.encoder,
        s.frozen,
        s.rgb,
        s.depth,
        s.gesture,
        s.semantic,
        s.pose,
        s.width,
        s.height,
        s.hidden,
        s.gru_layers
    );
    // appended only when not the dissertation's flat layer, so that earlier checkpoints still load
    let key = match (s.gesture, s.gesture_network) {
        (false, _) | (_, GestureNetwork::Flat) => key,
        (true, other) => format!("{key};gesture_network={other:?}"),
    };
    let digest = Sha256::digest(key.as_bytes());
    farm::files::hex(&digest[..8])
}

pub use farm::checkpoints::{latest, list, path as checkpoint_path};

/// Writes the trainer's checkpoint into `dir` and keeps the newest `keep` (0 keeps all).
pub fn save_in_dir(dir: &Path, t: &Trainer, keep: usize) -> Result<PathBuf, CheckpointError> {
    let path = checkpoint_path(dir, t.updates);
    save_trainer(&path, t)?;
    if keep > 0 {
        let all = list(dir);
        for (_, old) in all.iter().take(all.len().saturating_sub(keep)) {
            let _ = std::fs::remove_file(old);
        }
    }
    Ok(path)
}

/// Writes everything needed to continue training, atomically.
pub fn save_trainer(path: &Path, t: &Trainer) -> Result<(), CheckpointError> {
    let mut tensors: Vec<(String, Tensor)> =
        t.agent.vs.variables().into_iter().map(|(k, v)| (format!("model.{k}"), v)).collect();
    tensors.extend(t.opt.state().into_iter().map(|(k, v)| (format!("adam.{k}"), v)));
    let mut meta = BTreeMap::new();
    meta.insert("updates".into(), t.updates.to_string());
    meta.insert("frames".into(), t.frames.to_string());
    meta.insert("adam_step".into(), t.opt.step.to_string());
    meta.insert("rng_policy".into(), rng_to_string(&t.agent.rng));
    meta.insert("rng_trainer".into(), rng_to_string(&t.rng));
    write(path, &t.cfg, tensors, meta)
}

/// Writes an agent alone (weights and its sampling stream), e.g. for evaluation elsewhere.
pub fn save_agent(path: &Path, p: &Agent, cfg: &RunConfig) -> Result<(), CheckpointError> {
    let tensors = p.vs.variables().into_iter().map(|(k, v)| (format!("model.{k}"), v)).collect();
    let mut meta = BTreeMap::new();
    meta.insert("rng_policy".into(), rng_to_string(&p.rng));
    write(path, cfg, tensors, meta)
}

/// A trainer continuing from a checkpoint: weights, Adam state, update and frame counts (so
/// the lr schedule continues), random streams. Episodes start afresh.
pub fn resume_trainer(cfg: &RunConfig, n_envs: usize, device: Device, path: &Path) -> Result<Trainer, RestoreError> {
    let mut t = Trainer::build(cfg, n_envs, device, false)?;
    load_trainer(path, &mut t)?;
    Ok(t)
}

/// An agent for evaluation, its weights read from a checkpoint of a run with this config (the
/// ResNet-18 weights file need not be present: the checkpoint holds the trunk too).
pub fn load_agent(cfg: &RunConfig, n_envs: usize, device: Device, path: &Path) -> Result<Agent, RestoreError> {
    let mut agent = Agent::build(cfg, n_envs, device, false)?;
    load_agent_into(path, &mut agent, cfg)?;
    agent.note(format!("weights from {}", path.display()));
    Ok(agent)
}

/// Restores a trainer in place: weights, Adam state, counters, random streams.
pub fn load_trainer(path: &Path, t: &mut Trainer) -> Result<(), CheckpointError> {
    let (tensors, meta) = read(path, &t.cfg)?;
    load_variables(path, &tensors, &t.agent)?;
    let number = |key: &str| -> Result<u64, CheckpointError> {
        meta.get(key).and_then(|v| v.parse().ok()).ok_or_else(|| {
            error(path, format!("has no `{key}` counter (a policy-only checkpoint cannot resume training)"))
        })
    };
    let (updates, frames, adam_step) = (number("updates")?, number("frames")?, number("adam_step")?);
    let names: Vec<String> = t.opt.state().into_iter().map(|(k, _)| k).collect();
    tch::no_grad(|| {
        for name in names {
            let key = format!("adam.{name}");
            let src = tensors.get(&key).ok_or_else(|| error(path, format!("tensor `{key}` is missing")))?;
            let dst = t.opt.state_mut(&name).expect("state names come from the optimizer");
            check_shape(path, &key, src, dst)?;
            dst.copy_(src);
        }
        Ok(())
    })?;
    t.opt.step = adam_step as i64;
    t.updates = updates;
    t.frames = frames;
    t.agent.rng = rng_from(path, &meta, "rng_policy")?;
    t.rng = rng_from(path, &meta, "rng_trainer")?;
    Ok(())
}

/// Loads the network's weights (and sampling stream) into an agent: evaluation.
pub fn load_agent_into(path: &Path, p: &mut Agent, cfg: &RunConfig) -> Result<(), CheckpointError> {
    let (tensors, meta) = read(path, cfg)?;
    load_variables(path, &tensors, p)?;
    p.rng = rng_from(path, &meta, "rng_policy")?;
    Ok(())
}

fn load_variables(path: &Path, tensors: &HashMap<String, Tensor>, p: &Agent) -> Result<(), CheckpointError> {
    tch::no_grad(|| {
        for (name, mut var) in p.vs.variables() {
            let key = format!("model.{name}");
            let src = tensors.get(&key).ok_or_else(|| error(path, format!("tensor `{key}` is missing")))?;
            check_shape(path, &key, src, &var)?;
            var.copy_(src);
        }
        Ok(())
    })?;
    p.variables_loaded();
    Ok(())
}

fn check_shape(path: &Path, key: &str, src: &Tensor, dst: &Tensor) -> Result<(), CheckpointError> {
    if src.size() != dst.size() || src.kind() != dst.kind() {
        return Err(error(
            path,
            format!(
                "tensor `{key}` is {:?} {:?}, this network needs {:?} {:?}",
                src.kind(),
                src.size(),
                dst.kind(),
                dst.size()
            ),
        ));
    }
    Ok(())
}

fn dtype_of(kind: Kind) -> Option<Dtype> {
    Some(match kind {
        Kind::Float => Dtype::F32,
        Kind::Double => Dtype::F64,
        Kind::Half => Dtype::F16,
        Kind::BFloat16 => Dtype::BF16,
        Kind::Int64 => Dtype::I64,
        Kind::Int => Dtype::I32,
        Kind::Int16 => Dtype::I16,
        Kind::Uint8 => Dtype::U8,
        Kind::Bool => Dtype::BOOL,
        _ => return None,
    })
}

fn kind_of(dtype: Dtype) -> Option<Kind> {
    Some(match dtype {
        Dtype::F32 => Kind::Float,
        Dtype::F64 => Kind::Double,
        Dtype::F16 => Kind::Half,
        Dtype::BF16 => Kind::BFloat16,
        Dtype::I64 => Kind::Int64,
        Dtype::I32 => Kind::Int,
        Dtype::I16 => Kind::Int16,
        Dtype::U8 => Kind::Uint8,
        Dtype::BOOL => Kind::Bool,
        _ => return None,
    })
}

/// Digest of every tensor, names included, in name order.
fn write(
    path: &Path,
    cfg: &RunConfig,
    tensors: Vec<(String, Tensor)>,
    mut meta: BTreeMap<String, String>,
) -> Result<(), CheckpointError> {
    let mut blobs: Vec<(String, Dtype, Vec<usize>, Vec<u8>)> = Vec::with_capacity(tensors.len());
    for (name, t) in tensors {
        let t = t.detach().to_device(Device::Cpu).contiguous();
        let dtype =
            dtype_of(t.kind()).ok_or_else(|| error(path, format!("cannot store `{name}` of kind {:?}", t.kind())))?;
        let numel = t.numel();
        let mut data = vec![0u8; numel * t.kind().elt_size_in_bytes()];
        if numel > 0 {
            t.copy_data_u8(&mut data, numel);
        }
        blobs.push((name, dtype, t.size().iter().map(|d| *d as usize).collect(), data));
    }
    blobs.sort_by(|a, b| a.0.cmp(&b.0));
    meta.insert("format".into(), FORMAT.into());
    meta.insert("config_hash".into(), config_hash(cfg));
    meta.insert("config".into(), cfg.to_toml());
    meta.insert("sha256".into(), digest(blobs.iter().map(|b| (b.0.as_str(), b.3.as_slice()))));
    let views = blobs
        .iter()
        .map(|(n, d, s, data)| TensorView::new(*d, s.clone(), data).map(|v| (n.as_str(), v)))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| error(path, e.to_string()))?;
    let bytes =
        safetensors::serialize(views, Some(meta.into_iter().collect())).map_err(|e| error(path, e.to_string()))?;
    farm::files::write_atomic(path, &bytes).map_err(|e| error(path, format!("cannot write: {e}")))
}

/// Reads and checks a checkpoint: complete file, our format, intact data, same network.
fn read(path: &Path, cfg: &RunConfig) -> Result<(HashMap<String, Tensor>, HashMap<String, String>), CheckpointError> {
    let bytes = std::fs::read(path).map_err(|e| error(path, format!("cannot read: {e}")))?;
    // whole, ours, intact: the same check as checkpoint discovery
    let meta = farm::checkpoints::check_bytes(&bytes).map_err(|why| error(path, why))?;
    let st = SafeTensors::deserialize(&bytes).map_err(|e| error(path, e.to_string()))?;
    let views = st.tensors();
    let want = config_hash(cfg);
    let have = meta.get("config_hash").cloned().unwrap_or_default();
    if have != want {
        let theirs = meta
            .get("config")
            .and_then(|c| RunConfig::from_toml(c, "checkpoint").ok())
            .map(|c| NetSpec::from_config(&c).describe())
            .unwrap_or_else(|| "unknown".into());
        return Err(error(
            path,
            format!(
                "made for another network (config hash {have}: {theirs}); this run's config (hash {want}) builds {}",
                NetSpec::from_config(cfg).describe()
            ),
        ));
    }
    let mut tensors = HashMap::with_capacity(views.len());
    for (name, v) in views {
        let kind = kind_of(v.dtype())
            .ok_or_else(|| error(path, format!("tensor `{name}` has unsupported dtype {:?}", v.dtype())))?;
        let shape: Vec<i64> = v.shape().iter().map(|d| *d as i64).collect();
        let t = Tensor::f_from_data_size(v.data(), &shape, kind)
            .map_err(|e| error(path, format!("tensor `{name}`: {e}")))?;
        tensors.insert(name, t);
    }
    Ok((tensors, meta))
}

fn rng_to_string(r: &ChaCha8Rng) -> String {
    let seed = farm::files::hex(&r.get_seed());
    format!("{seed}:{}:{}", r.get_stream(), r.get_word_pos())
}

fn rng_from(path: &Path, meta: &HashMap<String, String>, key: &str) -> Result<ChaCha8Rng, CheckpointError> {
    let bad = || error(path, format!("metadata `{key}` is missing or malformed"));
    let s = meta.get(key).ok_or_else(bad)?;
    let mut parts = s.split(':');
    let (seed_hex, stream, pos) =
        (parts.next().ok_or_else(bad)?, parts.next().ok_or_else(bad)?, parts.next().ok_or_else(bad)?);
    if seed_hex.len() != 64 {
        return Err(bad());
    }
    let mut seed = [0u8; 32];
    for (i, b) in seed.iter_mut().enumerate() {
        *b = u8::from_str_radix(&seed_hex[2 * i..2 * i + 2], 16).map_err(|_| bad())?;
    }
    let mut r = ChaCha8Rng::from_seed(seed);
    r.set_stream(stream.parse().map_err(|_| bad())?);
    r.set_word_pos(pos.parse().map_err(|_| bad())?);
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::random_obs;
    use crate::net::agent::ActMode;
    use crate::net::spec::tests::tiny_config;
    use rand::Rng;

    fn trained_a_little(cfg: &RunConfig) -> Trainer {
        let mut t = Trainer::new(cfg, 2, Device::Cpu).unwrap();
        let mut o = random_obs(2, 16, 5);
        for s in 0..(cfg.ppo.rollout * 2 + 1) {
            o.envs.iter_mut().for_each(|e| {
                e.episode_start = s == 0;
                e.reward = 0.1;
            });
            t.step(&o.batch()).unwrap();
        }
        assert_eq!(t.updates, 2);
        t
    }

    #[test]
    fn save_then_load_gives_identical_outputs_and_state() {
        let cfg = tiny_config("both");
        let t = trained_a_little(&cfg);
        let dir = tempfile::tempdir().unwrap();
        let path = save_in_dir(dir.path(), &t, 3).unwrap();
        assert_eq!(latest(dir.path()), Some(path.clone()));

        let mut other = cfg.clone();
        other.run.seed = 99; // different initial weights
        let mut fresh = Trainer::new(&other, 2, Device::Cpu).unwrap();
        load_trainer(&path, &mut fresh).unwrap();
        assert_eq!((fresh.updates, fresh.frames, fresh.opt.step), (t.updates, t.frames, t.opt.step));
        for ((a, x), (b, y)) in t.opt.state().iter().zip(fresh.opt.state().iter()) {
            assert_eq!(a, b);
            assert!(x.equal(y), "{a}");
        }
        let (mut p, mut q) = (t.agent, fresh.agent);
        let o = random_obs(2, 16, 6);
        p.reset();
        assert_eq!(p.act(&o.batch(), ActMode::Greedy).unwrap(), q.act(&o.batch(), ActMode::Greedy).unwrap());
        // the sampling streams continue identically too
        assert_eq!(p.act(&o.batch(), ActMode::Sample).unwrap(), q.act(&o.batch(), ActMode::Sample).unwrap());

        // an agent-only load (evaluation)
        let mut r = load_agent(&cfg, 2, Device::Cpu, &path).unwrap();
        p.reset();
        r.reset();
        assert_eq!(p.act(&o.batch(), ActMode::Greedy).unwrap(), r.act(&o.batch(), ActMode::Greedy).unwrap());
    }

    #[test]
    fn damaged_files_give_one_clear_error_naming_the_file() {
        let cfg = tiny_config("vis_sem");
        let t = Trainer::new(&cfg, 2, Device::Cpu).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ckpt-00000000.safetensors");
        save_trainer(&path, &t).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let mut fresh = Trainer::new(&cfg, 2, Device::Cpu).unwrap();

        // truncated
        let cut = dir.path().join("cut.safetensors");
        std::fs::write(&cut, &bytes[..bytes.len() - 100]).unwrap();
        let e = load_trainer(&cut, &mut fresh).unwrap_err().to_string();
        assert!(e.contains("cut.safetensors") && e.contains("truncated"), "{e}");

        // one flipped bit in the data
        let flipped = dir.path().join("flipped.safetensors");
        let mut b = bytes.clone();
        let at = b.len() - 7;
        b[at] ^= 0x10;
        std::fs::write(&flipped, &b).unwrap();
        let e = load_trainer(&flipped, &mut fresh).unwrap_err().to_string();
        assert!(e.contains("flipped.safetensors") && e.contains("corrupted"), "{e}");

        // not ours / not a checkpoint at all
        let junk = dir.path().join("junk.safetensors");
        std::fs::write(&junk, rand::rng().random::<[u8; 32]>()).unwrap();
        let e = load_trainer(&junk, &mut fresh).unwrap_err().to_string();
        assert!(e.contains("junk.safetensors"), "{e}");
        let e = load_trainer(&dir.path().join("absent.safetensors"), &mut fresh).unwrap_err().to_string();
        assert!(e.contains("absent.safetensors") && e.contains("cannot read"), "{e}");
    }

    #[test]
    fn another_network_is_refused_by_config_hash() {
        let t = Trainer::new(&tiny_config("both"), 2, Device::Cpu).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ckpt-00000000.safetensors");
        save_trainer(&path, &t).unwrap();
        let mut other = Trainer::new(&tiny_config("vis_sem"), 2, Device::Cpu).unwrap();
        let e = load_trainer(&path, &mut other).unwrap_err().to_string();
        assert!(e.contains(&path.display().to_string()) && e.contains("config hash"), "{e}");
        assert!(e.contains("+Both") && e.contains("VisSem"), "{e}");
        // a change that does not touch the network (lr, total frames) still loads
        let mut cfg = tiny_config("both");
        cfg.ppo.lr = 1e-3;
        cfg.run.total_frames = 7;
        let mut same = Trainer::new(&cfg, 2, Device::Cpu).unwrap();
        load_trainer(&path, &mut same).unwrap();
    }

    #[test]
    fn latest_skips_temporary_files_and_pruning_keeps_the_newest() {
        let cfg = tiny_config("vis_sem");
        let mut t = Trainer::new(&cfg, 1, Device::Cpu).unwrap();
        let dir = tempfile::tempdir().unwrap();
        for u in [1, 2, 3, 4] {
            t.updates = u;
            save_in_dir(dir.path(), &t, 2).unwrap();
        }
        std::fs::write(dir.path().join(".ckpt-00000009.safetensors.tmp1"), b"partial").unwrap();
        let names: Vec<u64> = list(dir.path()).into_iter().map(|(u, _)| u).collect();
        assert_eq!(names, vec![3, 4]);
        assert_eq!(latest(dir.path()), Some(checkpoint_path(dir.path(), 4)));
    }
}
