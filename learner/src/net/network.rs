//! The policy network of §4.3.3 ([`PolicyNet`]): encoders, GRU, actor and critic, wired together.
//! Acting with it, one step for N envs, is `crate::net::agent`.
//!
//! ```text
//! RGB   224²×3 ─ ResNet-18 (frozen) ─ conv5 512×7×7 ─ 1×1 conv 512→128 ─ 1×1 conv 128→64 ─ FC 512 ┐
//! depth 224²×1 ─ (replicated to 3 channels, same trunk) ─ ... ─────────────────────────── FC 512 ┤
//! gesture 100×95 (zero when none is shown) ─ flatten ─ FC 512 ───────────────────────────────────┤ concat
//! target category ─ embedding 37→512 ─────────────────────────────────────────────────────────────┤ → GRU (2×512)
//! person pose (dx, dz, yaw/360), optional ─ FC 3→512 ─────────────────────────────────────────────┘   ├ actor  512-512-4
//!                                                                                                      └ critic 512-512-1
//! ```
//! ReLU follows every layer except the two outputs, as §4.3.3 says ("all layers are followed by a
//! ReLU"). Inputs the method or config switches off are left out of the concatenation (Vision
//! Only: 1024 wide). The actor and critic are read as "2 layers of 512, then the output layer".
//!
//! The gesture network is §4.3.3's flat layer by default, or the flat layer beside one shared per
//! frame, pooled over time and turned by the person's pose (`model.gesture_network`,
//! `crate::net::gesture_net`).
//!
//! Depth goes through the RGB trunk replicated to three channels (a grey image to an ImageNet
//! network): with frozen weights both modalities share one trunk and run as one batch.
//! Frozen conv5 features are computed once when acting and stored in the rollout, so PPO epochs
//! never re-run the ResNet; the trained encoders (small CNN, ResNet without weights) store the
//! raw frames instead.
//!
//! On CPUs, `model.encoder = "pretrained"` puts one frozen early-fusion RGB-D encoder (made by
//! `orchestrator encoder pretrain`) in place of the two visual branches: its 64×(H/8)×(W/8)
//! features are computed once when acting and stored, and PPO trains only the head on them
//! (1×1 conv 64→16, FC → hidden), one visual feature instead of two.

use farm::config::Encoder;
use shm_schema::{GESTURE_DIMS, TARGET_CATEGORIES, action};
use tch::nn::{self, RNN};
use tch::{Device, Kind, Tensor};

use crate::inputs::{self, Inputs, Staging, depth_unit, rgb_unit};
use crate::net::gesture_net::GestureNet;
use crate::net::layers::{ConvHead, FrozenTrunk, Mlp, Pretrained, SmallCnn, Visual};
use crate::net::resnet::{self, Resnet18};
use crate::net::spec::NetSpec;
use crate::net::stretches;
use crate::obs::EnvBatch;
use crate::stages::{Stage, StageClock};

/// The network. Variables live in the [`crate::net::agent::Agent`]'s var store under `resnet.` (the
/// frozen trunk), `encoder.` (the frozen pretrained encoder) and `visual.` (its head), `rgb.`,
/// `depth.`, `gesture.`, `target.`, `pose.`, `gru.`, `actor.`, `critic.`.
#[derive(Debug)]
pub struct PolicyNet {
    spec: NetSpec,
    frozen: Option<FrozenTrunk>,
    pretrained: Option<Pretrained>,
    rgb: Option<Visual>,
    depth: Option<Visual>,
    gesture: Option<GestureNet>,
    target: Option<nn::Embedding>,
    pose: Option<nn::Linear>,
    gru: nn::GRU,
    /// `gru`'s variables in torch's flat order, for PPO's packed call.
    gru_weights: Vec<Tensor>,
    actor: Mlp,
    critic: Mlp,
    /// Pinned host buffers the frames pass through to a GPU.
    staging: Staging,
}

impl PolicyNet {
    /// Builds the network for `spec` in `vs` (initialised from torch's seed); `bf16`: keep a bf16
    /// copy of the frozen trunk (CUDA with mixed precision).
    pub(crate) fn new(vs: &nn::VarStore, spec: &NetSpec, bf16: bool) -> PolicyNet {
        let root = vs.root();
        let h = spec.hidden;
        let visual_on = spec.rgb || spec.depth;
        let frozen = (spec.frozen && visual_on).then(|| FrozenTrunk::new(vs, bf16));
        let pretrained = (spec.fused() && visual_on)
            .then(|| Pretrained::new(vs, (spec.height, spec.width), spec.rgb, spec.depth, h));
        let side = (resnet::conv5_side(spec.height), resnet::conv5_side(spec.width));
        let visual = |name: &str, c_in: i64| {
            let p = &root / name;
            match (spec.encoder, spec.frozen) {
                (Encoder::Resnet18, true) => Visual::Frozen(ConvHead::new(&p, side, h)),
                (Encoder::Resnet18, false) => {
                    Visual::Resnet(Resnet18::new(&(&p / "resnet")), ConvHead::new(&p, side, h))
                }
                (Encoder::SmallCnn, _) => Visual::SmallCnn(SmallCnn::new(&p, c_in, (spec.height, spec.width), h)),
                (Encoder::Pretrained, _) => unreachable!("the pretrained encoder is one branch for both"),
            }
        };
        // the pretrained encoder is one branch for both (`pretrained` above)
        let rgb = (spec.rgb && !spec.fused()).then(|| visual("rgb", 3));
        let depth = (spec.depth && !spec.fused()).then(|| visual("depth", 1));
        let gesture = spec.gesture.then(|| {
            GestureNet::new(
                &(&root / "gesture"),
                spec.gesture_network,
                GESTURE_DIMS as i64,
                spec.gesture_pose_dims(),
                h,
            )
        });
        let target =
            spec.semantic.then(|| nn::embedding(&root / "target", TARGET_CATEGORIES as i64, h, Default::default()));
        let pose = spec.pose.then(|| nn::linear(&root / "pose", 3, h, Default::default()));
        let gru_cfg = nn::RNNConfig {
            num_layers: spec.gru_layers,
            batch_first: false,
            w_ih_init: nn::Init::Orthogonal { gain: 1.0 },
            w_hh_init: nn::Init::Orthogonal { gain: 1.0 },
            ..Default::default()
        };
        let gru = nn::gru(&root / "gru", spec.input_width(), h, gru_cfg);
        let gru_weights = stretches::flat_weights(vs, "gru", spec.gru_layers);
        PolicyNet {
            spec: spec.clone(),
            frozen,
            pretrained,
            rgb,
            depth,
            gesture,
            target,
            pose,
            gru,
            gru_weights,
            actor: Mlp::new(&(&root / "actor"), h, h, 2, action::COUNT as i64, 0.01),
            critic: Mlp::new(&(&root / "critic"), h, h, 2, 1, 1.0),
            staging: Staging::default(),
        }
    }

    /// One step's observation → the stored form (runs the frozen trunk, without gradients).
    pub(crate) fn prepare(&self, obs: &EnvBatch, device: Device, stages: &StageClock) -> Inputs {
        tch::no_grad(|| {
            let s = &self.spec;
            let visual = self.pretrained.as_ref().map(|p| {
                let (rgb, depth) = (self.staging.rgb(obs, device), self.staging.depth(obs, device));
                stages.lap(Stage::ActInputs);
                let features = p.features(&rgb, &depth);
                stages.lap(Stage::ActVisual);
                features
            });
            let mut rgb = (s.rgb && visual.is_none()).then(|| self.staging.rgb(obs, device));
            let mut depth = (s.depth && visual.is_none()).then(|| self.staging.depth(obs, device));
            stages.lap(Stage::ActInputs);
            if let Some(f) = &self.frozen {
                let n = obs.n() as i64;
                let mut images = Vec::new();
                if let Some(r) = &rgb {
                    images.push(rgb_unit(r));
                }
                if let Some(d) = &depth {
                    images.push(depth_unit(d).expand([-1, 3, -1, -1], false));
                }
                let feats = f.features(&Tensor::cat(&images, 0));
                let mut parts = feats.split(n, 0).into_iter();
                if rgb.is_some() {
                    rgb = parts.next();
                }
                if depth.is_some() {
                    depth = parts.next();
                }
                stages.lap(Stage::ActVisual);
            }
            let pose = s.pose.then(|| inputs::pose_tensor(obs, device));
            let gesture = s.gesture.then(|| {
                let mask = inputs::gesture_mask(obs, device).to_kind(Kind::Half).view([-1, 1, 1]);
                self.staging.gesture(obs, device) * mask
            });
            let target = s.semantic.then(|| inputs::target_tensor(obs, device));
            stages.lap(Stage::ActInputs);
            Inputs { rgb, depth, visual, gesture, gesture_index: None, target, pose }
        })
    }

    /// Stored inputs `[B, ..]` → concatenated features `[B, D]`.
    pub(crate) fn encode(&self, x: &Inputs) -> Tensor {
        self.encode_with(x, None, None)
    }

    /// [`PolicyNet::encode`], with the gesture network's output for `x`'s rows given when it was
    /// computed beforehand (acting's `GestureMemo`); `stages` times the visual branches apart
    /// (acting).
    pub(crate) fn encode_with(&self, x: &Inputs, gesture: Option<Tensor>, stages: Option<&StageClock>) -> Tensor {
        let mut parts = Vec::new();
        if let (Some(p), Some(t)) = (&self.pretrained, &x.visual) {
            parts.push(p.forward(t));
        }
        if let (Some(enc), Some(t)) = (&self.rgb, &x.rgb) {
            parts.push(enc.forward(t, false));
        }
        if let (Some(enc), Some(t)) = (&self.depth, &x.depth) {
            parts.push(enc.forward(t, true));
        }
        if let Some(s) = stages {
            s.lap(Stage::ActVisual);
        }
        if let (Some(l), Some(t)) = (&self.gesture, &x.gesture) {
            parts.push(gesture.unwrap_or_else(|| {
                // distinct gestures are read once, then gathered for every row that shows them
                let pose =
                    self.spec.gesture_reads_pose().then(|| inputs::frame_pose(x.pose.as_ref().expect("the pose")));
                l.read(t, x.gesture_index.as_ref(), pose.as_ref())
            }));
        }
        if let (Some(e), Some(t)) = (&self.target, &x.target) {
            parts.push(t.apply(e).relu());
        }
        if let (Some(l), Some(t)) = (&self.pose, &x.pose) {
            parts.push(t.apply(l).relu());
        }
        Tensor::cat(&parts, 1)
    }

    /// The GRU on one step `[1, B, D]` from the memory `h` `[L, B, H]`, zeroed for the envs where
    /// `keep` `[1, B]` is 0 (an episode starts).
    pub(crate) fn step(&self, x: &Tensor, h: &Tensor, keep: &Tensor) -> (Tensor, Tensor) {
        let (out, h) = self.gru.seq_init(x, &nn::GRUState(h * keep.view([1, -1, 1])));
        (out, h.0)
    }

    /// GRU output → (logits `[.., action::COUNT]`, value `[..]`).
    pub(crate) fn heads(&self, h: &Tensor) -> (Tensor, Tensor) {
        (self.actor.forward(h), self.critic.forward(h).squeeze_dim(-1))
    }

    /// Whole sequences for PPO: inputs `[T, B, ..]` from the memory `h0` `[L, B, H]`, reset where
    /// `starts[t * B + b]` → (logits `[T, B, action::COUNT]`, values `[T, B]`).
    pub fn evaluate(&self, x: &Inputs, h0: &Tensor, starts: &[bool]) -> (Tensor, Tensor) {
        let size = x.fields().iter().find_map(|(_, t)| t.map(|t| t.size())).expect("network has inputs");
        let (t, b) = (size[0], size[1]);
        let feats = self.encode(&x.map(|v| v.flatten(0, 1))).view([t, b, -1]);
        let (out, _) = stretches::gru_over_stretches(&self.gru_weights, self.spec.gru_layers, &feats, h0, starts);
        self.heads(&out)
    }

    /// The gesture network, when the method shows gestures.
    pub(crate) fn gesture_net(&self) -> Option<&GestureNet> {
        self.gesture.as_ref()
    }

    /// The pretrained RGB-D encoder, when the network has one.
    pub(crate) fn pretrained(&self) -> Option<&Pretrained> {
        self.pretrained.as_ref()
    }

    /// The frozen ImageNet trunk, when the network has one.
    pub(crate) fn frozen(&self) -> Option<&FrozenTrunk> {
        self.frozen.as_ref()
    }

    pub(crate) fn spec(&self) -> &NetSpec {
        &self.spec
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::{random_encoder_weights, random_obs, tiny_frozen_config};
    use crate::net::agent::Agent;
    use crate::ppo::rollout::Rollout;

    /// The tiny network on the pretrained encoder: 64×64 (the encoder's frame), hidden 32.
    fn frozen_config(dir: &std::path::Path) -> farm::config::RunConfig {
        let mut c = tiny_frozen_config(&random_encoder_weights(dir, 64).unwrap());
        c.model.hidden = 32;
        c.ppo.rollout = 4;
        c
    }

    /// Features are computed once when acting and stored: the rollout's copy equals the trunk
    /// re-run on the frames, PPO's sequence evaluation gives the values acting gave, and only the
    /// head (not the trunk) has gradients.
    #[test]
    fn stored_features_equal_recomputed_ones() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = frozen_config(dir.path());
        let mut p = Agent::new(&cfg, 2, Device::Cpu).unwrap();
        assert!(p.notes().iter().any(|n| n.contains("pretrained RGB-D encoder")), "{:?}", p.notes());
        assert_eq!(p.spec.input_width(), 3 * 32, "one visual feature, gesture, target");
        let vars = p.vs.variables();
        assert!(vars.iter().filter(|(k, _)| k.starts_with("encoder.")).all(|(_, v)| !v.requires_grad()));
        assert!(vars.keys().all(|k| !k.starts_with("rgb.") && !k.starts_with("depth.")));
        let h0 = p.hidden().copy();
        let mut r = Rollout::new(4, 2, &h0);
        let mut frames = Vec::new();
        let mut acted_values = Vec::new();
        for t in 0..4u64 {
            let mut o = random_obs(2, 64, 20 + t);
            o.envs.iter_mut().for_each(|e| e.episode_start = t == 0);
            let (x, st) = p.prepare(0, &o.batch()).unwrap();
            assert!(x.rgb.is_none() && x.depth.is_none());
            assert_eq!(x.visual.as_ref().unwrap().size(), [2, 64, 8, 8]);
            let f = p.forward(0, &x, st);
            acted_values.extend(f.values.clone());
            let acted =
                crate::net::agent::Actions { actions: vec![0; 2], log_probs: vec![0.0; 2], values: f.values.clone() };
            r.push(&x, &[t == 0; 2], &acted, &[true; 2]);
            p.commit(0, f, &o.batch());
            frames.push(o);
        }
        let stored = r.inputs().unwrap().visual.as_ref().unwrap().shallow_clone();
        let trunk = p.net.pretrained().unwrap();
        for (t, o) in frames.iter().enumerate() {
            let b = o.batch();
            let again = trunk.features(&inputs::rgb_tensor(&b, Device::Cpu), &inputs::depth_tensor(&b, Device::Cpu));
            assert!(stored.get(t as i64).allclose(&again, 1e-5, 1e-6, false), "step {t}");
        }
        let idx = Tensor::from_slice(&[0i64, 1]);
        let x = r.minibatch(&idx).unwrap();
        let starts = [true, true, false, false, false, false, false, false];
        let (logits, values) = p.net.evaluate(&x, &h0, &starts);
        let got = Vec::<f32>::try_from(values.detach().flatten(0, -1)).unwrap();
        for (a, b) in acted_values.iter().zip(&got) {
            assert!((a - b).abs() < 1e-5, "{acted_values:?} vs {got:?}");
        }
        logits.sum(Kind::Float).backward();
        for (k, v) in p.vs.variables() {
            if k.starts_with("visual.") {
                assert!(v.grad().defined() && v.grad().abs().sum(Kind::Float).double_value(&[]) > 0.0, "{k}");
            }
        }
    }

    /// T4.7's variants drop a modality: its input channels are zeroed, so what the frames show
    /// there does not matter.
    #[test]
    fn a_switched_off_modality_is_zeroed() {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = frozen_config(dir.path());
        cfg.model.rgb = false;
        let p = Agent::new(&cfg, 2, Device::Cpu).unwrap();
        let a = random_obs(2, 64, 1);
        let mut b = random_obs(2, 64, 1);
        b.rgb.iter_mut().for_each(|v| *v = v.wrapping_add(77));
        let feats = |o: &crate::obs::OwnedObs| p.prepare(0, &o.batch()).unwrap().0.visual.as_ref().unwrap().copy();
        assert!(feats(&a).equal(&feats(&b)), "RGB is off: it must not change the features");
        let mut c = random_obs(2, 64, 1);
        c.depth.iter_mut().for_each(|v| *v = v.wrapping_add(999));
        assert!(!feats(&a).equal(&feats(&c)), "depth is on");
    }

    #[test]
    fn missing_or_mismatched_weights_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = frozen_config(dir.path());
        cfg.model.encoder_weights = Some(dir.path().join("absent.safetensors"));
        let e = Agent::new(&cfg, 1, Device::Cpu).unwrap_err().to_string();
        assert!(e.contains("absent.safetensors") && e.contains("orchestrator encoder pretrain"), "{e}");
        let mut cfg = frozen_config(dir.path());
        cfg.env.width = 32;
        cfg.env.height = 32;
        let e = Agent::new(&cfg, 1, Device::Cpu).unwrap_err().to_string();
        assert!(e.contains("rgbd64-random.safetensors") && e.contains("64×64") && e.contains("32×32"), "{e}");
    }
}
