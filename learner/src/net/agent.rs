//! The acting agent ([`Agent`]): the policy network of `crate::net::network`, its variables, and
//! the recurrent state of each of N envs. It acts one step for N envs: prepare the inputs, run the
//! network from the current memory, choose actions (sampled or greedy, from its own seeded
//! stream), then commit the new memory. PPO drives the same four steps (`crate::ppo::trainer`).

use farm::config::{Encoder, RunConfig};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use shm_schema::action;
use tch::nn;
use tch::{Device, Kind, Tensor};

use crate::encoder::{EncoderFileError, load_weights as load_encoder};
use crate::inputs::{Inputs, Prepared};
use crate::net::gesture_memo::GestureMemo;
use crate::net::network::PolicyNet;
use crate::net::resnet::{self, WeightsError};
use crate::net::spec::NetSpec;
use crate::obs::{EnvBatch, ObsError};
use crate::stages::{Stage, StageClock};

/// Why an agent could not be built for a config.
#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    #[error(transparent)]
    Weights(#[from] WeightsError),
    #[error(transparent)]
    Encoder(#[from] EncoderFileError),
    #[error("config: {0}")]
    Config(String),
}

/// Actions chosen for one step of N envs.
#[derive(Clone, Debug, PartialEq)]
pub struct Actions {
    /// Indices of [`shm_schema::action`]: MoveAhead, RotateLeft, RotateRight, Stop.
    pub actions: Vec<i64>,
    pub log_probs: Vec<f32>,
    pub values: Vec<f32>,
}

/// Sampled (training, or the Random baseline) or argmax (evaluation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ActMode {
    Sample,
    Greedy,
}

/// One forward at one step, not yet committed to the recurrent state.
#[derive(Debug)]
pub(crate) struct Forward {
    /// `[N * action::COUNT]` on the host.
    pub logits: Vec<f32>,
    pub values: Vec<f32>,
    pub hidden: Tensor,
    pub starts: Vec<bool>,
}

/// The acting agent: the network, its variables and the recurrent state of each of N envs.
#[derive(Debug)]
pub struct Agent {
    pub spec: NetSpec,
    pub vs: nn::VarStore,
    pub net: PolicyNet,
    device: Device,
    n_envs: usize,
    /// `[layers, N, hidden]`.
    hidden: Tensor,
    /// Envs whose message was lost: their state is reset at their next message.
    force_reset: Vec<bool>,
    /// Action sampling; part of the checkpoint.
    pub(crate) rng: ChaCha8Rng,
    /// Each env's gesture features, recomputed only when its gesture or the layer changes.
    gestures: GestureMemo,
    notes: Vec<String>,
    /// Acting's stages timed, when on (the trainer's updates use it too).
    pub(crate) stages: StageClock,
}

impl Agent {
    /// Builds the network for `cfg` and `n_envs` envs on `device`, loading the ResNet-18
    /// weights when the config names them. Variables are initialised from the run seed.
    pub fn new(cfg: &RunConfig, n_envs: usize, device: Device) -> Result<Agent, AgentError> {
        Agent::build(cfg, n_envs, device, true)
    }

    /// Builds the network; `load_weights`: read the configured ResNet-18 or pretrained encoder
    /// file (not when a checkpoint is about to overwrite every variable anyway:
    /// `crate::ppo::checkpoint::load_agent`).
    pub(crate) fn build(
        cfg: &RunConfig,
        n_envs: usize,
        device: Device,
        load_weights: bool,
    ) -> Result<Agent, AgentError> {
        let spec = NetSpec::from_config(cfg);
        if n_envs == 0 {
            return Err(AgentError::Config("a policy needs at least one env".into()));
        }
        crate::device::flush_denormals();
        let vs = nn::VarStore::new(device);
        let bf16 = crate::device::use_bf16(device, cfg.ppo.mixed_precision);
        let seed = farm::seed::mix(cfg.run.seed, &[0x6E65_7477]) as i64;
        let net = crate::device::seeded(seed, || PolicyNet::new(&vs, &spec, bf16));
        let mut notes = vec![spec.describe()];
        if spec.random() {
            notes.push("Random: uniform actions; the network is neither used nor trained".into());
        } else if let (Some(path), Some(f), true) = (&cfg.model.resnet_weights, net.frozen(), load_weights) {
            let n = resnet::load_torchvision(&vs, "resnet.", path)?;
            f.refresh(&vs);
            notes.push(format!("loaded {n} ResNet-18 tensors from {} (frozen)", path.display()));
        } else if let (Some(path), Some(_), true) = (&cfg.model.encoder_weights, net.pretrained(), load_weights) {
            load_encoder(path, &vs, "encoder", (cfg.env.width, cfg.env.height))?;
            notes.push(format!("loaded the pretrained RGB-D encoder from {} (frozen)", path.display()));
        }
        if spec.encoder == Encoder::Resnet18 && !spec.frozen && (spec.rgb || spec.depth) && !spec.random() {
            let msg = "NO IMAGENET WEIGHTS: model.resnet_weights is not set, so the ResNet-18 encoders start \
                       from random weights and are TRAINED end to end — not the dissertation's frozen ImageNet \
                       backbone. Supply a torchvision resnet18 state dict to reproduce §4.3.3, or the label-free \
                       trunk of `orchestrator encoder pretrain --trunk resnet18 --size 224 --device cuda`.";
            tracing::warn!("{msg}");
            notes.push(msg.into());
        }
        let hidden = Tensor::zeros([spec.gru_layers, n_envs as i64, spec.hidden], (Kind::Float, device));
        Ok(Agent {
            rng: farm::seed::rng(cfg.run.seed, &[0x6163_7473]),
            spec,
            vs,
            net,
            device,
            n_envs,
            hidden,
            force_reset: vec![false; n_envs],
            gestures: GestureMemo::default(),
            notes,
            stages: StageClock::default(),
        })
    }

    pub fn n_envs(&self) -> usize {
        self.n_envs
    }

    pub fn device(&self) -> Device {
        self.device
    }

    /// What was built and loaded, for the run log (the first line describes the network).
    pub fn notes(&self) -> &[String] {
        &self.notes
    }

    /// Adds a line to [`Agent::notes`].
    pub(crate) fn note(&mut self, line: String) {
        self.notes.push(line);
    }

    /// Kind of the stored frozen features (bf16 on CUDA with mixed precision), if any.
    pub fn feature_kind(&self) -> Option<Kind> {
        self.net.frozen().map(|f| f.feature_kind())
    }

    /// Trainable parameter count.
    pub fn trainable_parameters(&self) -> i64 {
        self.vs.variables().values().filter(|t| t.requires_grad()).map(|t| t.numel() as i64).sum()
    }

    /// An action for each env: sampled (training; the Random baseline) or the most likely one
    /// (evaluation; the Random baseline still samples).
    pub fn act(&mut self, obs: &EnvBatch, mode: ActMode) -> Result<Actions, ObsError> {
        self.act_explained(obs, mode).map(|(a, _)| a)
    }

    /// [`Agent::act`], with each env's probability of every action (`[N * action::COUNT]`):
    /// what a person watching the robot reads (`learner act`).
    pub fn act_explained(&mut self, obs: &EnvBatch, mode: ActMode) -> Result<(Actions, Vec<f32>), ObsError> {
        let (inputs, starts) = self.prepare(0, obs)?;
        let fwd = self.forward(0, &inputs, starts);
        let probs = fwd.logits.chunks(action::COUNT).flat_map(|l| log_softmax(l).into_iter().map(f32::exp)).collect();
        let actions = self.choose(&fwd, mode);
        self.commit(0, fwd, obs);
        Ok((actions, probs))
    }

    /// Forgets every env's memory (a new evaluation round).
    pub fn reset(&mut self) {
        let _ = self.hidden.zero_();
        self.force_reset.iter_mut().for_each(|r| *r = false);
    }

    /// Checks the batch of envs `at..at + obs.n()` of the N (all of them, or one group of an
    /// acting round), converts it to the stored form, and works out where memory resets.
    pub(crate) fn prepare<'a>(&self, at: usize, obs: &EnvBatch<'a>) -> Result<(Prepared<'a>, Vec<bool>), ObsError> {
        self.prepare_envs(at..at + obs.n(), obs)
    }

    /// [`Agent::prepare`] of a batch that must hold envs `envs` of the N.
    fn prepare_envs<'a>(
        &self,
        envs: std::ops::Range<usize>,
        obs: &EnvBatch<'a>,
    ) -> Result<(Prepared<'a>, Vec<bool>), ObsError> {
        if envs.end > self.n_envs {
            return Err(ObsError::Shape(format!("envs {envs:?} of a policy made for {}", self.n_envs)));
        }
        obs.validate(envs.len(), self.hw())?;
        let starts =
            obs.envs.iter().zip(&self.force_reset[envs]).map(|(e, f)| e.episode_start || e.lost || *f).collect();
        let inputs = if self.spec.random() { Inputs::none() } else { self.net.prepare(obs, self.device, &self.stages) };
        Ok((Prepared::new(inputs, obs), starts))
    }

    fn hw(&self) -> (usize, usize) {
        (self.spec.height as usize, self.spec.width as usize)
    }

    /// The network on one step of envs `at..at + starts.len()`, from their memory (reset where
    /// `starts`).
    pub(crate) fn forward(&mut self, at: usize, x: &Inputs, starts: Vec<bool>) -> Forward {
        let n = starts.len();
        let memory = self.hidden.narrow(1, at as i64, n as i64).contiguous();
        if self.spec.random() {
            return Forward { logits: vec![0.0; n * action::COUNT], values: vec![0.0; n], hidden: memory, starts };
        }
        tch::no_grad(|| {
            let gesture = match (self.net.gesture_net(), &x.gesture, &x.gesture_index) {
                (Some(l), Some(g), None) => {
                    let part = self.gestures.parts(l, g, at, self.n_envs);
                    let pose = self
                        .spec
                        .gesture_reads_pose()
                        .then(|| crate::inputs::frame_pose(x.pose.as_ref().expect("the pose comes with the gesture")));
                    Some(l.join(&part, pose.as_ref()))
                }
                _ => None,
            };
            self.stages.lap(Stage::ActRest);
            let feats = self.net.encode_with(x, gesture, Some(&self.stages)).unsqueeze(0);
            let keep: Vec<f32> = starts.iter().map(|s| if *s { 0.0 } else { 1.0 }).collect();
            let keep = Tensor::from_slice(&keep).to_device(self.device).view([1, -1]);
            let (out, hidden) = self.net.step(&feats, &memory, &keep);
            let (logits, values) = self.net.heads(&out.squeeze_dim(0));
            self.stages.lap(Stage::ActRest);
            let logits =
                Vec::<f32>::try_from(logits.to_kind(Kind::Float).to_device(Device::Cpu).flatten(0, -1)).unwrap();
            let values = Vec::<f32>::try_from(values.to_kind(Kind::Float).to_device(Device::Cpu)).unwrap();
            self.stages.lap(Stage::ActSample);
            Forward { logits, values, hidden, starts }
        })
    }

    /// Picks actions from a forward's logits (host side, from the agent's own random stream).
    pub(crate) fn choose(&mut self, fwd: &Forward, mode: ActMode) -> Actions {
        let n = fwd.values.len();
        let mut out =
            Actions { actions: Vec::with_capacity(n), log_probs: Vec::with_capacity(n), values: fwd.values.clone() };
        let count = action::COUNT;
        for i in 0..n {
            let logp = log_softmax(&fwd.logits[i * count..(i + 1) * count]);
            let a = if mode == ActMode::Greedy && !self.spec.random() {
                (0..count).max_by(|&a, &b| logp[a].total_cmp(&logp[b])).unwrap()
            } else {
                let u: f32 = self.rng.random();
                let mut acc = 0.0;
                // where rounding leaves the cumulative sum under `u`: the last action, Stop
                let mut pick = action::STOP as usize;
                for (k, lp) in logp.iter().enumerate() {
                    acc += lp.exp();
                    if u < acc {
                        pick = k;
                        break;
                    }
                }
                pick
            };
            out.actions.push(a as i64);
            out.log_probs.push(logp[a]);
        }
        out
    }

    /// Makes a forward's memory (of envs `at..`) the current one; lost envs reset at their next
    /// message.
    pub(crate) fn commit(&mut self, at: usize, fwd: Forward, obs: &EnvBatch) {
        let n = fwd.starts.len();
        if n == self.n_envs {
            self.hidden = fwd.hidden;
        } else {
            tch::no_grad(|| self.hidden.narrow(1, at as i64, n as i64).copy_(&fwd.hidden));
        }
        for (r, e) in self.force_reset[at..at + n].iter_mut().zip(obs.envs) {
            *r = e.lost;
        }
    }

    pub(crate) fn hidden(&self) -> &Tensor {
        &self.hidden
    }

    /// Re-syncs derived copies after the variables were overwritten (checkpoint load).
    pub(crate) fn variables_loaded(&self) {
        if let Some(f) = self.net.frozen() {
            f.refresh(&self.vs);
        }
    }
}

/// Numerically stable log-softmax of a few logits.
pub fn log_softmax(x: &[f32]) -> Vec<f32> {
    let m = x.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
    let lse = m + x.iter().map(|v| (v - m).exp()).sum::<f32>().ln();
    x.iter().map(|v| v - lse).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::random_obs;
    use crate::net::spec::tests::tiny_config;
    use crate::obs::GestureKind;
    use farm::config::GestureNetwork;

    #[test]
    fn acting_shapes_memory_and_resets() {
        let cfg = tiny_config("both");
        let mut p = Agent::new(&cfg, 3, Device::Cpu).unwrap();
        let mut o = random_obs(3, 16, 1);
        let a = p.act(&o.batch(), ActMode::Sample).unwrap();
        assert_eq!(a.actions.len(), 3);
        assert!(a.actions.iter().all(|a| (0..4).contains(a)));
        assert!(a.log_probs.iter().all(|l| *l <= 0.0 && l.is_finite()));
        // the same observation again, mid-episode: memory changes the values
        o.envs.iter_mut().for_each(|e| e.episode_start = false);
        let b = p.act(&o.batch(), ActMode::Greedy).unwrap();
        assert_ne!(a.values, b.values);
        // an episode start resets memory: same values as the very first step
        o.envs.iter_mut().for_each(|e| e.episode_start = true);
        let c = p.act(&o.batch(), ActMode::Greedy).unwrap();
        for (x, y) in a.values.iter().zip(&c.values) {
            assert!((x - y).abs() < 1e-5);
        }
    }

    #[test]
    fn no_gesture_means_zero_gesture_input() {
        let cfg = tiny_config("both");
        let mut p = Agent::new(&cfg, 2, Device::Cpu).unwrap();
        let mut o = random_obs(2, 16, 2);
        o.envs.iter_mut().for_each(|e| e.gesture = GestureKind::None);
        let a = p.act(&o.batch(), ActMode::Greedy).unwrap();
        o.gesture.iter_mut().for_each(|v| *v = half::f16::from_f32(0.7));
        p.reset();
        let b = p.act(&o.batch(), ActMode::Greedy).unwrap();
        assert_eq!(a.values, b.values);
    }

    /// The turned network with the person's pose: the per-frame layers read the gesture's 95
    /// values alone and the pose's 4 (right, forward, cos and sin of the facing) join after the
    /// pooling; the stored step keeps the gesture and the pose apart, so that a gesture is stored
    /// once whatever the pose.
    #[test]
    fn the_turned_network_reads_the_pose_apart_from_the_frames() {
        let mut cfg = tiny_config("both");
        cfg.model.person_pose = true;
        cfg.model.gesture_network = GestureNetwork::FlatAndTurned;
        let p = Agent::new(&cfg, 2, Device::Cpu).unwrap();
        let v = p.vs.variables();
        assert_eq!(v["gesture.frame0.weight"].size(), [64, 95]);
        assert_eq!(v["gesture.place.weight"].size(), [16, 4]);
        let mut o = random_obs(2, 16, 4);
        o.envs[0].gesture = GestureKind::Referencing;
        o.envs[0].person_pose = [1.5, 2.0, 0.25];
        o.envs[1].gesture = GestureKind::None;
        let (x, _) = p.prepare(0, &o.batch()).unwrap();
        let g = x.gesture.as_ref().unwrap().to_kind(Kind::Float);
        assert_eq!(g.size(), [2, 100, 95]);
        assert_eq!(g.get(1).abs().sum(Kind::Float).double_value(&[]), 0.0);
        let pose = crate::inputs::frame_pose(x.pose.as_ref().unwrap()).get(0);
        let want = Tensor::from_slice(&[1.5f32, 2.0, 0.0, 1.0]);
        assert!(pose.allclose(&want, 1e-3, 1e-3, false), "{pose}");
        // the flat layer keeps §4.3.3's width, with the pose a separate input as before
        cfg.model.gesture_network = GestureNetwork::Flat;
        let p = Agent::new(&cfg, 2, Device::Cpu).unwrap();
        assert_eq!(p.vs.variables()["gesture.weight"].size(), [32, 100 * 95]);
    }

    #[test]
    fn sequence_evaluation_matches_step_by_step_acting() {
        // the PPO re-run over whole sequences (fused GRU between resets) must give the values
        // the policy computed step by step when acting
        let cfg = tiny_config("both");
        let mut p = Agent::new(&cfg, 2, Device::Cpu).unwrap();
        let h0 = p.hidden().copy();
        let starts = [[true, true], [false, false], [false, true], [false, false], [true, false]];
        let mut stored = Vec::new();
        let mut acted = Vec::new();
        let first = random_obs(2, 16, 10);
        for (t, s) in starts.iter().enumerate() {
            let mut o = random_obs(2, 16, 10 + t as u64);
            // env 0 shows one gesture all along (acting reuses its features), env 1 a new one
            // at every step
            let g = o.gesture.len() / 2;
            o.gesture[..g].copy_from_slice(&first.gesture[..g]);
            o.envs[0].episode_start = s[0];
            o.envs[1].episode_start = s[1];
            let (x, st) = p.prepare(0, &o.batch()).unwrap();
            let f = p.forward(0, &x, st);
            acted.extend(f.values.clone());
            p.commit(0, f, &o.batch());
            stored.push(x.map(|t| t.copy())); // `o` is dropped at the end of the iteration
        }
        let stack = |get: fn(&Inputs) -> Option<&Tensor>| {
            Some(Tensor::stack(&stored.iter().map(|x| get(x).unwrap().shallow_clone()).collect::<Vec<_>>(), 0))
        };
        let x = Inputs {
            rgb: stack(|x| x.rgb.as_ref()),
            depth: stack(|x| x.depth.as_ref()),
            visual: None,
            gesture: stack(|x| x.gesture.as_ref()),
            gesture_index: None,
            target: stack(|x| x.target.as_ref()),
            pose: None,
        };
        let starts: Vec<bool> = starts.iter().flatten().copied().collect();
        let (_, values) = tch::no_grad(|| p.net.evaluate(&x, &h0, &starts));
        let values = Vec::<f32>::try_from(values.flatten(0, -1)).unwrap();
        for (a, b) in acted.iter().zip(&values) {
            assert!((a - b).abs() < 1e-5, "{acted:?} vs {values:?}");
        }
    }

    /// The dissertation's network on the CPU: frozen trunk out of the optimizer, conv5 features
    /// (512×7×7 per modality) are what the rollout stores, 2048 features into a 2-layer GRU.
    #[test]
    fn faithful_network_stores_frozen_conv5_features() {
        let dir = tempfile::tempdir().unwrap();
        let weights = crate::bench::random_resnet_weights(dir.path()).unwrap();
        let cfg = crate::bench::faithful_config(&weights);
        let mut p = Agent::new(&cfg, 1, Device::Cpu).unwrap();
        assert!(p.notes().iter().any(|n| n.contains("loaded 100 ResNet-18 tensors")), "{:?}", p.notes());
        assert_eq!(p.spec.input_width(), 2048);
        let vars = p.vs.variables();
        assert!(vars.iter().filter(|(k, _)| k.starts_with("resnet.")).all(|(_, v)| !v.requires_grad()));
        assert_eq!(vars["gru.weight_ih_l1"].size(), vec![3 * 512, 512]);
        assert_eq!(vars["rgb.fc.weight"].size(), vec![512, 64 * 7 * 7]);
        let o = random_obs(1, 224, 3);
        let (x, _) = p.prepare(0, &o.batch()).unwrap();
        assert_eq!(x.rgb.as_ref().unwrap().size(), vec![1, 512, 7, 7]);
        assert_eq!(x.depth.as_ref().unwrap().size(), vec![1, 512, 7, 7]);
        let a = p.act(&o.batch(), ActMode::Sample).unwrap();
        assert!(a.values[0].is_finite());
        // an Adam over the policy sees only the trainable part
        let opt = crate::ppo::optim::Adam::new(&p.vs, 1e-3, 1e-5);
        assert_eq!(opt.state().len() / 2, vars.values().filter(|v| v.requires_grad()).count());
        // 2 × (1×1 convs 74k + FC 1.6M) + gesture FC 4.9M + embedding 19k + GRU 5.5M + heads 1.1M
        assert!((14_000_000..15_000_000).contains(&p.trainable_parameters()), "{}", p.trainable_parameters());
    }

    /// On a GPU machine: the same agent on CUDA and on the CPU agrees. Skipped (with a line
    /// saying so) where there is no GPU.
    #[test]
    fn cuda_agent_agrees_with_cpu() {
        crate::device::load_cuda_backend();
        if !tch::Cuda::is_available() {
            eprintln!("cuda_agent_agrees_with_cpu: skipped, no CUDA device on this machine");
            return;
        }
        let cfg = tiny_config("both");
        let mut cpu = Agent::new(&cfg, 3, Device::Cpu).unwrap();
        let mut gpu = Agent::new(&cfg, 3, Device::Cuda(0)).unwrap();
        tch::no_grad(|| {
            let src = cpu.vs.variables();
            for (k, mut v) in gpu.vs.variables() {
                v.copy_(&src[&k].to_device(Device::Cuda(0)));
            }
        });
        let o = random_obs(3, 16, 4);
        let (a, b) = (cpu.act(&o.batch(), ActMode::Greedy).unwrap(), gpu.act(&o.batch(), ActMode::Greedy).unwrap());
        for (x, y) in a.values.iter().zip(&b.values) {
            assert!((x - y).abs() < 1e-3, "{a:?} vs {b:?}");
        }
    }

    #[test]
    fn trained_resnet_without_weights_is_said_loudly() {
        let cfg = RunConfig::from_toml(
            "[run]\nmethod = \"vis_sem\"\n[env]\nwidth = 32\nheight = 32\n[model]\nhidden = 16\ngru_layers = 1\n",
            "x.toml",
        )
        .unwrap();
        let p = Agent::new(&cfg, 1, Device::Cpu).unwrap();
        assert!(p.notes().iter().any(|n| n.contains("NO IMAGENET WEIGHTS")));
        // the trunks are trainable
        assert!(p.vs.variables().iter().any(|(k, v)| k.starts_with("rgb.resnet.layer4") && v.requires_grad()));
    }
    #[test]
    fn distinct_gestures_give_the_plain_path_s_outputs_and_gradients() {
        // PPO's minibatches encode each distinct gesture once and gather; the outputs and the
        // gradients must be those of encoding every row — with the flat layer, and turned by
        // the person's pose, which moves at every step while the gestures stay
        distinct_gestures_read_as_every_row(&tiny_config("both"));
        let mut cfg = tiny_config("both");
        cfg.model.person_pose = true;
        cfg.model.gesture_network = GestureNetwork::FlatAndTurned;
        distinct_gestures_read_as_every_row(&cfg);
    }

    /// The steps' inputs `[N, ..]` stacked into `[T, N, ..]`, every field.
    fn stacked(steps: &[Inputs]) -> Inputs {
        let field = |pick: fn(&Inputs) -> &Option<Tensor>| {
            let all: Option<Vec<Tensor>> = steps.iter().map(|s| pick(s).as_ref().map(|t| t.shallow_clone())).collect();
            all.map(|all| Tensor::stack(&all, 0))
        };
        Inputs {
            rgb: field(|s| &s.rgb),
            depth: field(|s| &s.depth),
            visual: field(|s| &s.visual),
            gesture: field(|s| &s.gesture),
            gesture_index: None,
            target: field(|s| &s.target),
            pose: field(|s| &s.pose),
        }
    }

    fn distinct_gestures_read_as_every_row(cfg: &RunConfig) {
        let mut p = Agent::new(cfg, 2, Device::Cpu).unwrap();
        let h0 = p.hidden().copy();
        let mut r = crate::ppo::rollout::Rollout::new(6, 2, &h0);
        let first = random_obs(2, 16, 40);
        // each step's inputs as the agent prepared them: the oracle, kept apart from the rollout
        let mut steps = Vec::new();
        for t in 0..6u64 {
            let mut o = random_obs(2, 16, 50 + t);
            // env 0 keeps its gesture all along; env 1 shows a new one at every step
            let g = o.gesture.len() / 2;
            o.gesture[..g].copy_from_slice(&first.gesture[..g]);
            for (k, e) in o.envs.iter_mut().enumerate() {
                e.episode_start = t == 0;
                e.person_pose = [0.3 * t as f32, k as f32 - 0.5, 0.1 * t as f32];
            }
            let (x, st) = p.prepare(0, &o.batch()).unwrap();
            steps.push(x.map(|t| t.copy()));
            let f = p.forward(0, &x, st);
            let acted = Actions { actions: vec![0; 2], log_probs: vec![0.0; 2], values: f.values.clone() };
            r.push(&x, &[t == 0, t == 0], &acted, &[true, true]);
            p.commit(0, f, &o.batch());
        }
        let every_row = stacked(&steps);
        let table = r.gestures().unwrap();
        assert_eq!(table.len(), 1 + 6, "env 0: one gesture; env 1: six");
        // both envs: 12 rows of the 7 gestures; env 1 alone: 6 rows of its own 6 (env 0's is
        // left out of its minibatch)
        for (envs, distinct_shown) in [(&[1i64, 0][..], 7), (&[1], 6)] {
            let idx = Tensor::from_slice(envs);
            let distinct = r.minibatch(&idx).unwrap();
            assert_eq!(distinct.gesture.as_ref().unwrap().size()[0], distinct_shown, "{envs:?}");
            // every row's inputs as its env showed them, the gestures without the table
            let plain = every_row.map(|t| t.index_select(1, &idx));
            let starts = vec![false; 6 * envs.len()];
            let run = |x: &Inputs| {
                for mut v in p.vs.trainable_variables() {
                    v.zero_grad();
                }
                let (logits, values) = p.net.evaluate(x, &h0.index_select(1, &idx), &starts);
                (logits.sum(Kind::Float) + values.square().sum(Kind::Float)).backward();
                let grads: Vec<Tensor> = p.vs.trainable_variables().iter().map(|v| v.grad().copy()).collect();
                (logits.detach(), values.detach(), grads)
            };
            let (l1, v1, g1) = run(&distinct);
            let (l2, v2, g2) = run(&plain);
            assert!(l1.allclose(&l2, 1e-5, 1e-6, false) && v1.allclose(&v2, 1e-5, 1e-6, false), "{envs:?}");
            for (a, b) in g1.iter().zip(&g2) {
                assert!(a.allclose(b, 1e-4, 1e-6, false), "{envs:?}: gradients differ");
            }
        }
    }
}
