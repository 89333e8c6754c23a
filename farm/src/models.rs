//! Shipped models: a trained policy in a folder of its own, for people who do not train. The
//! folder holds the policy's weights alone (no optimizer state), its run's config, its card,
//! and the check: episodes it must reproduce. Anything that takes a run directory as a
//! checkpoint (`eval`, `follow`, `live`, the Python package) takes such a folder too.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::checkpoints::{check_bytes, digest};

/// The weights: a checkpoint in the learner's format with only the network's tensors.
pub const WEIGHTS: &str = "policy.safetensors";
/// The config of the run that trained it (what the learner builds the network from).
pub const CONFIG: &str = "config.toml";
/// What it is, how it was made and how well it does, for a person.
pub const CARD: &str = "card.md";
/// The episodes it must reproduce, for the test.
pub const CHECK: &str = "check.json";
/// Where the repository keeps them.
pub const DIR: &str = "models";

/// Training's tensors and metadata, left out of a shipped model.
const TRAINING_ONLY_TENSORS: &str = "adam.";
const TRAINING_ONLY_META: [&str; 2] = ["adam_step", "rng_trainer"];

/// Whether `dir` is a shipped model's folder.
pub fn is_model(dir: &Path) -> bool {
    dir.join(WEIGHTS).is_file() && dir.join(CONFIG).is_file()
}

/// The model folders in `dir`, by name.
pub fn list(dir: &Path) -> Vec<PathBuf> {
    let mut found: Vec<PathBuf> =
        std::fs::read_dir(dir).into_iter().flatten().flatten().map(|e| e.path()).filter(|p| is_model(p)).collect();
    found.sort();
    found
}

/// A checkpoint's bytes without what only training reads (Adam's moments and step, the
/// trainer's stream); the network's tensors, the policy's sampling stream and the counters
/// stay, and the checksum is made anew. The error is one reason, without the path.
pub fn policy_only(checkpoint: &[u8]) -> Result<Vec<u8>, String> {
    let mut meta = check_bytes(checkpoint)?;
    let st = safetensors::SafeTensors::deserialize(checkpoint).map_err(|e| e.to_string())?;
    let mut kept: Vec<(String, safetensors::tensor::TensorView<'_>)> =
        st.tensors().into_iter().filter(|(name, _)| !name.starts_with(TRAINING_ONLY_TENSORS)).collect();
    if kept.is_empty() {
        return Err("it holds no network tensors".into());
    }
    kept.sort_by(|a, b| a.0.cmp(&b.0));
    for key in TRAINING_ONLY_META {
        meta.remove(key);
    }
    meta.insert("sha256".into(), digest(kept.iter().map(|(n, v)| (n.as_str(), v.data()))));
    safetensors::serialize(kept.iter().map(|(n, v)| (n.as_str(), v.clone())), Some(meta)).map_err(|e| e.to_string())
}

/// The episodes a shipped model must reproduce: `eval --split SPLIT --max-programs N --modes
/// normal` on the model, each episode's outcome, and how many may differ on another machine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Check {
    pub split: String,
    pub max_programs: usize,
    pub episodes: Vec<Outcome>,
    /// At most this many episodes may have another outcome (float rounding elsewhere).
    pub tolerance: usize,
    /// How the tolerance was measured.
    pub tolerance_why: String,
}

/// One episode as the check compares it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Outcome {
    pub program: u64,
    pub success_first_stop: bool,
    /// The step of the first stop, if it stopped.
    pub first_stop: Option<u32>,
    pub steps: u32,
}

impl Outcome {
    pub fn of(e: &crate::metrics::EpisodeResult) -> Outcome {
        let first = e.stops.first();
        Outcome {
            program: e.program,
            success_first_stop: first.is_some_and(|s| s.success),
            first_stop: first.map(|s| s.step),
            steps: e.steps,
        }
    }
}

impl Check {
    /// Successes at the first stop, of the recorded episodes.
    pub fn successes(&self) -> usize {
        self.episodes.iter().filter(|o| o.success_first_stop).count()
    }

    /// The recorded episodes that `got` does not reproduce (a missing one counts), each as
    /// "program P: recorded … got …".
    pub fn differences(&self, got: &[Outcome]) -> Vec<String> {
        self.episodes
            .iter()
            .filter_map(|want| {
                let found = got.iter().find(|o| o.program == want.program);
                match found {
                    Some(o) if o == want => None,
                    Some(o) => Some(format!("program {}: recorded {want:?}, got {o:?}", want.program)),
                    None => Some(format!("program {}: recorded {want:?}, no episode", want.program)),
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn checkpoint(tensors: &[(&str, &[u8])], meta: &[(&str, &str)]) -> Vec<u8> {
        let mut sorted: Vec<(&str, &[u8])> = tensors.to_vec();
        sorted.sort();
        let mut m: HashMap<String, String> = meta.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        m.insert("format".into(), crate::checkpoints::FORMAT.into());
        m.insert("sha256".into(), digest(sorted.iter().copied()));
        let views: Vec<_> = sorted
            .iter()
            .map(|(n, d)| (*n, safetensors::tensor::TensorView::new(safetensors::Dtype::U8, vec![d.len()], d).unwrap()))
            .collect();
        safetensors::serialize(views, Some(m)).unwrap()
    }

    #[test]
    fn policy_only_keeps_the_network_and_drops_the_optimizer() {
        let full = checkpoint(
            &[("model.w", &[1, 2, 3]), ("adam.exp_avg.w", &[4, 5, 6]), ("model.b", &[7])],
            &[("frames", "42"), ("adam_step", "3"), ("rng_trainer", "x"), ("rng_policy", "y"), ("config", "[run]")],
        );
        let slim = policy_only(&full).unwrap();
        let meta = check_bytes(&slim).expect("the slim file verifies against its own checksum");
        let st = safetensors::SafeTensors::deserialize(&slim).unwrap();
        let mut names: Vec<String> = st.names().into_iter().map(String::from).collect();
        names.sort();
        assert_eq!(names, ["model.b", "model.w"]);
        assert_eq!(st.tensor("model.w").unwrap().data(), &[1, 2, 3]);
        for kept in ["frames", "rng_policy", "config"] {
            assert!(meta.contains_key(kept), "{kept} kept");
        }
        assert!(!meta.contains_key("adam_step") && !meta.contains_key("rng_trainer"));
    }

    #[test]
    fn policy_only_refuses_a_damaged_file() {
        let mut full = checkpoint(&[("model.w", &[1, 2, 3])], &[]);
        let n = full.len();
        full[n - 1] ^= 0xff;
        assert!(policy_only(&full).unwrap_err().contains("checksum"));
    }

    #[test]
    fn differences_name_each_episode_not_reproduced() {
        let o =
            |program, success_first_stop, steps| Outcome { program, success_first_stop, first_stop: Some(3), steps };
        let check = Check {
            split: "val".into(),
            max_programs: 3,
            episodes: vec![o(0, true, 5), o(10, false, 100), o(20, true, 9)],
            tolerance: 0,
            tolerance_why: String::new(),
        };
        assert_eq!(check.successes(), 2);
        assert!(check.differences(&check.episodes).is_empty());
        let d = check.differences(&[o(0, true, 5), o(10, false, 99)]);
        assert_eq!(d.len(), 2);
        assert!(d[0].starts_with("program 10:") && d[1].contains("no episode"), "{d:?}");
    }
}
