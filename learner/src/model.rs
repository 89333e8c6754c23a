//! The policy network of §4.3.3 and the [`Policy`] that acts with it, one step for N envs.
//!
//! ```text
//! RGB   224²×3 ─ ResNet-18 (frozen) ─ conv5 512×7×7 ─ 1×1 conv 512→128 ─ 1×1 conv 128→64 ─ FC 512 ┐
//! depth 224²×1 ─ (replicated to 3 channels, same trunk) ─ ... ─────────────────────────── FC 512 ┤
//! gesture 100×95 (zero when none is shown) ─ flatten ─ FC 512 ────────────────────────────────────┤ concat
//! target category ─ embedding 37→512 ─────────────────────────────────────────────────────────────┤ → GRU (2×512)
//! person pose (dx, dz, yaw/360), optional ─ FC 3→512 ─────────────────────────────────────────────┘   ├ actor  512-512-4
//!                                                                                                      └ critic 512-512-1
//! ```
//! ReLU follows every layer except the two outputs, as §4.3.3 says ("all layers are followed by a
//! ReLU"). Inputs the method or config switches off are left out of the concatenation (Vision
//! Only: 1024 wide). The actor and critic are read as "2 layers of 512, then the output layer".
//!
//! Depth goes through the RGB trunk replicated to three channels (a grey image to an ImageNet
//! network): with frozen weights both modalities share one trunk and run as one batch.
//! Frozen conv5 features are computed once when acting and stored in the rollout, so PPO epochs
//! never re-run the ResNet; the trained encoders (small CNN, ResNet without weights) store the
//! raw frames instead.

use farm::config::{Encoder, Method, RunConfig};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use tch::nn::{self, RNN};
use tch::{Device, Kind, Tensor};

use shm_schema::{GESTURE_DIMS, GESTURE_FRAMES, TARGET_CATEGORIES, action};

use crate::obs::{ObsBatch, ObsError};
use crate::resnet::{self, CONV5_CHANNELS, Resnet18, WeightsError};

/// What the network looks like for a run: which inputs, which encoder, how wide.
#[derive(Clone, Debug, PartialEq)]
pub struct NetSpec {
    pub method: Method,
    pub encoder: Encoder,
    /// ResNet-18 with user-supplied ImageNet weights, frozen. False: every encoder is trained.
    pub frozen: bool,
    pub rgb: bool,
    pub depth: bool,
    pub gesture: bool,
    pub semantic: bool,
    pub pose: bool,
    pub height: i64,
    pub width: i64,
    pub hidden: i64,
    pub gru_layers: i64,
}

impl NetSpec {
    pub fn from_config(cfg: &RunConfig) -> NetSpec {
        let m = &cfg.model;
        NetSpec {
            method: cfg.run.method,
            encoder: m.encoder,
            frozen: m.encoder == Encoder::Resnet18 && m.resnet_weights.is_some(),
            rgb: m.rgb,
            depth: m.depth,
            gesture: cfg.run.method.gesture(),
            semantic: cfg.run.method.semantic(),
            pose: m.person_pose,
            height: cfg.env.height as i64,
            width: cfg.env.width as i64,
            hidden: m.hidden,
            gru_layers: m.gru_layers,
        }
    }

    /// Random acts uniformly and learns nothing.
    pub fn random(&self) -> bool {
        self.method == Method::Random
    }

    /// Width of the concatenated features fed to the GRU.
    pub fn input_width(&self) -> i64 {
        let n = [self.rgb, self.depth, self.gesture, self.semantic, self.pose].iter().filter(|b| **b).count();
        self.hidden * n as i64
    }

    /// One line for logs.
    pub fn describe(&self) -> String {
        let mut inputs = Vec::new();
        for (on, name) in [
            (self.rgb, "rgb"),
            (self.depth, "depth"),
            (self.gesture, "gesture"),
            (self.semantic, "target"),
            (self.pose, "person-pose"),
        ] {
            if on {
                inputs.push(name);
            }
        }
        let enc = match (self.encoder, self.frozen) {
            (Encoder::Resnet18, true) => "ResNet-18 (frozen, ImageNet weights)",
            (Encoder::Resnet18, false) => "ResNet-18 (TRAINED from random weights)",
            (Encoder::SmallCnn, _) => "small CNN (trained)",
        };
        format!(
            "{}: {} {}x{}, inputs [{}] → {} → GRU {}x{} → actor/critic",
            self.method.label(),
            enc,
            self.width,
            self.height,
            inputs.join(", "),
            self.input_width(),
            self.gru_layers,
            self.hidden
        )
    }
}

/// The network's inputs in the form the rollout keeps them, leading dims `[B]` or `[T, B]`.
#[derive(Debug)]
pub struct Inputs {
    /// Raw u8 `[.., H, W, 3]`, or frozen conv5 features `[.., 512, h, w]`.
    pub rgb: Option<Tensor>,
    /// Raw 16-bit depth patterns in Int16 `[.., H, W]`, or frozen conv5 features.
    pub depth: Option<Tensor>,
    /// Half `[.., 100, 95]`, zero where no gesture is shown.
    pub gesture: Option<Tensor>,
    /// Target index, i64 `[..]`.
    pub target: Option<Tensor>,
    /// f32 `[.., 3]`.
    pub pose: Option<Tensor>,
}

impl Inputs {
    pub fn map(&self, f: impl Fn(&Tensor) -> Tensor) -> Inputs {
        Inputs {
            rgb: self.rgb.as_ref().map(&f),
            depth: self.depth.as_ref().map(&f),
            gesture: self.gesture.as_ref().map(&f),
            target: self.target.as_ref().map(&f),
            pose: self.pose.as_ref().map(&f),
        }
    }

    pub fn fields(&self) -> [(&'static str, Option<&Tensor>); 5] {
        [
            ("rgb", self.rgb.as_ref()),
            ("depth", self.depth.as_ref()),
            ("gesture", self.gesture.as_ref()),
            ("target", self.target.as_ref()),
            ("pose", self.pose.as_ref()),
        ]
    }
}

/// One step's inputs, which on the CPU may read the observation batch's buffers in place (no
/// host copy): they live no longer than those buffers (`'a`). The rollout copies them.
#[derive(Debug)]
pub(crate) struct Prepared<'a> {
    pub inputs: Inputs,
    _buffers: std::marker::PhantomData<&'a [u8]>,
}

impl std::ops::Deref for Prepared<'_> {
    type Target = Inputs;
    fn deref(&self) -> &Inputs {
        &self.inputs
    }
}

/// RGB u8 `[B, H, W, 3]` → f32 `[B, 3, H, W]` in 0..1.
pub fn rgb_unit(raw: &Tensor) -> Tensor {
    raw.permute([0, 3, 1, 2]).to_kind(Kind::Float) / 255.0
}

/// Depth as Int16 bit patterns `[B, H, W]` → f32 `[B, 1, H, W]` in 0..1 (0..10 m).
pub fn depth_unit(raw: &Tensor) -> Tensor {
    (raw.to_kind(Kind::Int).bitwise_and(0xFFFF).to_kind(Kind::Float) / 65535.0).unsqueeze(1)
}

/// Images in 0..1 with 1 or 3 channels → ImageNet-normalised 3 channels.
fn resnet_input(x: &Tensor) -> Tensor {
    let x = if x.size()[1] == 1 { x.expand([-1, 3, -1, -1], false) } else { x.shallow_clone() };
    resnet::imagenet_normalize(&x)
}

fn linear(p: nn::Path, i: i64, o: i64, gain: f64) -> nn::Linear {
    nn::linear(
        p,
        i,
        o,
        nn::LinearConfig { ws_init: nn::Init::Orthogonal { gain }, bs_init: Some(nn::Init::Const(0.0)), bias: true },
    )
}

/// The trained part after a ResNet trunk: two 1×1 convolutions 512→128→64, flatten, FC.
#[derive(Debug)]
struct ConvHead {
    reduce1: nn::Conv2D,
    reduce2: nn::Conv2D,
    fc: nn::Linear,
}

impl ConvHead {
    fn new(p: &nn::Path, side: (i64, i64), hidden: i64) -> ConvHead {
        let c = nn::ConvConfig::default();
        ConvHead {
            reduce1: nn::conv2d(p / "reduce1", CONV5_CHANNELS, 128, 1, c),
            reduce2: nn::conv2d(p / "reduce2", 128, 64, 1, c),
            fc: nn::linear(p / "fc", 64 * side.0 * side.1, hidden, Default::default()),
        }
    }

    fn forward(&self, conv5: &Tensor) -> Tensor {
        conv5
            .to_kind(Kind::Float)
            .apply(&self.reduce1)
            .relu()
            .apply(&self.reduce2)
            .relu()
            .flatten(1, -1)
            .apply(&self.fc)
            .relu()
    }
}

/// A small CNN for CPU runs: a 4×4 stride-4 "patchify" convolution (32 channels), two 3×3
/// stride-2 convolutions (64, 64), average pooled to at most 4×4, FC. About 2.2 M multiply-adds
/// for a 64×64 frame — PPO re-runs it over every stored frame in every epoch, so it must be cheap.
#[derive(Debug)]
struct SmallCnn {
    convs: [nn::Conv2D; 3],
    pool: Option<[i64; 2]>,
    fc: nn::Linear,
}

impl SmallCnn {
    fn new(p: &nn::Path, c_in: i64, hw: (i64, i64), hidden: i64) -> SmallCnn {
        let patch = nn::ConvConfig { stride: 4, ..Default::default() };
        let down = nn::ConvConfig { stride: 2, padding: 1, ..Default::default() };
        // ⌊n/4⌋ after the patches, then ⌈·/2⌉ twice
        let side = |n: i64| ((n / 4 + 1) / 2 + 1) / 2;
        let (h, w) = (side(hw.0), side(hw.1));
        let (ph, pw) = (h.min(4), w.min(4));
        SmallCnn {
            convs: [
                nn::conv2d(p / "conv1", c_in, 32, 4, patch),
                nn::conv2d(p / "conv2", 32, 64, 3, down),
                nn::conv2d(p / "conv3", 64, 64, 3, down),
            ],
            pool: (ph != h || pw != w).then_some([ph, pw]),
            fc: nn::linear(p / "fc", 64 * ph * pw, hidden, Default::default()),
        }
    }

    fn forward(&self, x: &Tensor) -> Tensor {
        let mut y = x.shallow_clone();
        for c in &self.convs {
            y = y.apply(c).relu();
        }
        if let Some(s) = self.pool {
            y = y.adaptive_avg_pool2d(s);
        }
        y.flatten(1, -1).apply(&self.fc).relu()
    }
}

/// One visual encoder (RGB or depth).
#[derive(Debug)]
enum Visual {
    /// After the shared frozen trunk: reads stored conv5 features.
    Frozen(ConvHead),
    /// Its own ResNet-18, trained from random weights.
    Resnet(Resnet18, ConvHead),
    SmallCnn(SmallCnn),
}

impl Visual {
    /// `x`: stored form, `[B, ..]`; `depth`: whether it is a depth input.
    fn forward(&self, x: &Tensor, depth: bool) -> Tensor {
        let unit = || if depth { depth_unit(x) } else { rgb_unit(x) };
        match self {
            Visual::Frozen(head) => head.forward(x),
            Visual::Resnet(trunk, head) => head.forward(&trunk.forward(&resnet_input(&unit()))),
            Visual::SmallCnn(cnn) => cnn.forward(&unit()),
        }
    }
}

/// The frozen ImageNet trunk shared by RGB and depth, and its bf16 copy for CUDA.
#[derive(Debug)]
struct FrozenTrunk {
    trunk: Resnet18,
    bf16: Option<(nn::VarStore, Resnet18)>,
}

impl FrozenTrunk {
    /// conv5 features of images in 0..1, `[B, C, H, W]`, in the kind the rollout stores.
    fn features(&self, x: &Tensor) -> Tensor {
        let x = resnet_input(x);
        match &self.bf16 {
            Some((_, t)) => t.forward(&x.to_kind(Kind::BFloat16)),
            None => self.trunk.forward(&x),
        }
    }

    fn feature_kind(&self) -> Kind {
        if self.bf16.is_some() { Kind::BFloat16 } else { Kind::Float }
    }

    /// Copies the (f32) trunk weights into the bf16 copy; after loading weights.
    fn refresh(&self, vs: &nn::VarStore) {
        if let Some((half, _)) = &self.bf16 {
            let src = vs.variables();
            tch::no_grad(|| {
                for (name, mut dst) in half.variables() {
                    dst.copy_(&src[&name].to_kind(dst.kind()));
                }
            });
        }
    }
}

#[derive(Debug)]
struct Mlp {
    layers: Vec<nn::Linear>,
}

impl Mlp {
    /// `depth` hidden layers of `width` with ReLU, then a linear output with gain `out_gain`.
    fn new(p: &nn::Path, input: i64, width: i64, depth: usize, out: i64, out_gain: f64) -> Mlp {
        let mut layers = Vec::new();
        let mut i = input;
        for l in 0..depth {
            layers.push(linear(p / format!("{l}"), i, width, 2f64.sqrt()));
            i = width;
        }
        layers.push(linear(p / "out", i, out, out_gain));
        Mlp { layers }
    }

    fn forward(&self, x: &Tensor) -> Tensor {
        let last = self.layers.len() - 1;
        let mut y = x.shallow_clone();
        for (i, l) in self.layers.iter().enumerate() {
            y = y.apply(l);
            if i < last {
                y = y.relu();
            }
        }
        y
    }
}

/// The network. Variables live in the [`Policy`]'s var store under `resnet.` (the frozen trunk),
/// `rgb.`, `depth.`, `gesture.`, `target.`, `pose.`, `gru.`, `actor.`, `critic.`.
#[derive(Debug)]
pub struct PolicyNet {
    spec: NetSpec,
    frozen: Option<FrozenTrunk>,
    rgb: Option<Visual>,
    depth: Option<Visual>,
    gesture: Option<nn::Linear>,
    target: Option<nn::Embedding>,
    pose: Option<nn::Linear>,
    gru: nn::GRU,
    actor: Mlp,
    critic: Mlp,
}

impl PolicyNet {
    fn new(vs: &nn::VarStore, spec: &NetSpec, bf16: bool) -> PolicyNet {
        let root = vs.root();
        let h = spec.hidden;
        let visual_on = spec.rgb || spec.depth;
        let frozen = (spec.frozen && visual_on).then(|| FrozenTrunk {
            trunk: Resnet18::new(&(&root / "resnet")),
            bf16: bf16.then(|| {
                let mut half = nn::VarStore::new(vs.device());
                let t = Resnet18::new(&(half.root() / "resnet"));
                half.bfloat16();
                half.freeze();
                (half, t)
            }),
        });
        if frozen.is_some() {
            for (name, v) in vs.variables() {
                if name.starts_with("resnet.") {
                    let _ = v.set_requires_grad(false);
                }
            }
        }
        let side = (resnet::conv5_side(spec.height), resnet::conv5_side(spec.width));
        let visual = |name: &str, c_in: i64| {
            let p = &root / name;
            match (spec.encoder, spec.frozen) {
                (Encoder::Resnet18, true) => Visual::Frozen(ConvHead::new(&p, side, h)),
                (Encoder::Resnet18, false) => {
                    Visual::Resnet(Resnet18::new(&(&p / "resnet")), ConvHead::new(&p, side, h))
                }
                (Encoder::SmallCnn, _) => Visual::SmallCnn(SmallCnn::new(&p, c_in, (spec.height, spec.width), h)),
            }
        };
        let rgb = spec.rgb.then(|| visual("rgb", 3));
        let depth = spec.depth.then(|| visual("depth", 1));
        let gesture = spec
            .gesture
            .then(|| nn::linear(&root / "gesture", (GESTURE_FRAMES * GESTURE_DIMS) as i64, h, Default::default()));
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
        PolicyNet {
            spec: spec.clone(),
            frozen,
            rgb,
            depth,
            gesture,
            target,
            pose,
            gru,
            actor: Mlp::new(&(&root / "actor"), h, h, 2, action::COUNT as i64, 0.01),
            critic: Mlp::new(&(&root / "critic"), h, h, 2, 1, 1.0),
        }
    }

    /// One step's observation → the stored form (runs the frozen trunk, without gradients).
    fn prepare(&self, obs: &ObsBatch, device: Device) -> Inputs {
        tch::no_grad(|| {
            let s = &self.spec;
            let mut rgb = s.rgb.then(|| obs.rgb_tensor(device));
            let mut depth = s.depth.then(|| obs.depth_tensor(device));
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
            }
            let gesture = s.gesture.then(|| {
                let mask = obs.gesture_mask(device).to_kind(Kind::Half).view([-1, 1, 1]);
                obs.gesture_tensor(device) * mask
            });
            Inputs {
                rgb,
                depth,
                gesture,
                target: s.semantic.then(|| obs.target_tensor(device)),
                pose: s.pose.then(|| obs.pose_tensor(device)),
            }
        })
    }

    /// Stored inputs `[B, ..]` → concatenated features `[B, D]`.
    fn encode(&self, x: &Inputs) -> Tensor {
        let mut parts = Vec::new();
        if let (Some(enc), Some(t)) = (&self.rgb, &x.rgb) {
            parts.push(enc.forward(t, false));
        }
        if let (Some(enc), Some(t)) = (&self.depth, &x.depth) {
            parts.push(enc.forward(t, true));
        }
        if let (Some(l), Some(t)) = (&self.gesture, &x.gesture) {
            parts.push(t.to_kind(Kind::Float).flatten(1, -1).apply(l).relu());
        }
        if let (Some(e), Some(t)) = (&self.target, &x.target) {
            parts.push(t.apply(e).relu());
        }
        if let (Some(l), Some(t)) = (&self.pose, &x.pose) {
            parts.push(t.apply(l).relu());
        }
        Tensor::cat(&parts, 1)
    }

    /// The GRU over `[T, B, D]` from `h0` `[L, B, H]`, zeroing an env's state where `keep[t, b]`
    /// is 0 (an episode starts at t). Runs the fused GRU over the stretches between resets.
    fn recurrent(&self, x: &Tensor, h0: &Tensor, keep: &Tensor, any_start: &[bool]) -> (Tensor, Tensor) {
        let t_len = x.size()[0];
        let mut h = h0.shallow_clone();
        let mut outs = Vec::new();
        let mut t0 = 0i64;
        for t in 1..=t_len {
            if t == t_len || any_start[t as usize] {
                h = &h * keep.get(t0).view([1, -1, 1]);
                let (o, s) = self.gru.seq_init(&x.narrow(0, t0, t - t0), &nn::GRUState(h));
                outs.push(o);
                h = s.0;
                t0 = t;
            }
        }
        (Tensor::cat(&outs, 0), h)
    }

    /// GRU output → (logits `[.., action::COUNT]`, value `[..]`).
    fn heads(&self, h: &Tensor) -> (Tensor, Tensor) {
        (self.actor.forward(h), self.critic.forward(h).squeeze_dim(-1))
    }

    /// Whole sequences for PPO: inputs `[T, B, ..]` → (logits `[T, B, action::COUNT]`, values `[T, B]`).
    pub fn evaluate(&self, x: &Inputs, h0: &Tensor, keep: &Tensor, any_start: &[bool]) -> (Tensor, Tensor) {
        let size = x.fields().iter().find_map(|(_, t)| t.map(|t| t.size())).expect("network has inputs");
        let (t, b) = (size[0], size[1]);
        let feats = self.encode(&x.map(|v| v.flatten(0, 1))).view([t, b, -1]);
        let (out, _) = self.recurrent(&feats, h0, keep, any_start);
        self.heads(&out)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error(transparent)]
    Weights(#[from] WeightsError),
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

/// The network, its variables and the recurrent state of each of N envs.
#[derive(Debug)]
pub struct Policy {
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
    notes: Vec<String>,
}

impl Policy {
    /// Builds the network for `cfg` and `n_envs` envs on `device`, loading the ResNet-18
    /// weights when the config names them. Variables are initialised from the run seed.
    pub fn new(cfg: &RunConfig, n_envs: usize, device: Device) -> Result<Policy, ModelError> {
        Policy::build(cfg, n_envs, device, true)
    }

    /// A policy for evaluation, its weights read from a checkpoint of a run with this config
    /// (the ResNet-18 weights file need not be present: the checkpoint holds the trunk too).
    pub fn from_checkpoint(
        cfg: &RunConfig,
        n_envs: usize,
        device: Device,
        checkpoint: &std::path::Path,
    ) -> Result<Policy, crate::LearnerError> {
        let mut p = Policy::build(cfg, n_envs, device, false)?;
        crate::checkpoint::load_policy(checkpoint, &mut p, cfg)?;
        p.notes.push(format!("weights from {}", checkpoint.display()));
        Ok(p)
    }

    /// Builds the network; `load_weights`: read the configured ResNet-18 file (not when a
    /// checkpoint is about to overwrite every variable anyway).
    pub(crate) fn build(
        cfg: &RunConfig,
        n_envs: usize,
        device: Device,
        load_weights: bool,
    ) -> Result<Policy, ModelError> {
        let spec = NetSpec::from_config(cfg);
        if n_envs == 0 {
            return Err(ModelError::Config("a policy needs at least one env".into()));
        }
        crate::device::flush_denormals();
        tch::manual_seed(farm::seed::mix(cfg.run.seed, &[0x6E65_7477]) as i64);
        let vs = nn::VarStore::new(device);
        let bf16 = crate::device::use_bf16(device, cfg.ppo.mixed_precision);
        let net = PolicyNet::new(&vs, &spec, bf16);
        let mut notes = vec![spec.describe()];
        if spec.random() {
            notes.push("Random: uniform actions; the network is neither used nor trained".into());
        } else if let (Some(path), Some(f), true) = (&cfg.model.resnet_weights, &net.frozen, load_weights) {
            let n = resnet::load_torchvision(&vs, "resnet.", path)?;
            f.refresh(&vs);
            notes.push(format!("loaded {n} ResNet-18 tensors from {} (frozen)", path.display()));
        }
        if spec.encoder == Encoder::Resnet18 && !spec.frozen && (spec.rgb || spec.depth) && !spec.random() {
            let msg = "NO IMAGENET WEIGHTS: model.resnet_weights is not set, so the ResNet-18 encoders start \
                       from random weights and are TRAINED end to end — not the dissertation's frozen ImageNet \
                       backbone. Supply a torchvision resnet18 state dict to reproduce §4.3.3.";
            tracing::warn!("{msg}");
            notes.push(msg.into());
        }
        let hidden = Tensor::zeros([spec.gru_layers, n_envs as i64, spec.hidden], (Kind::Float, device));
        Ok(Policy {
            rng: farm::seed::rng(cfg.run.seed, &[0x6163_7473]),
            spec,
            vs,
            net,
            device,
            n_envs,
            hidden,
            force_reset: vec![false; n_envs],
            notes,
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

    /// Kind of the stored frozen features (bf16 on CUDA with mixed precision), if any.
    pub fn feature_kind(&self) -> Option<Kind> {
        self.net.frozen.as_ref().map(|f| f.feature_kind())
    }

    /// Trainable parameter count.
    pub fn trainable_parameters(&self) -> i64 {
        self.vs.variables().values().filter(|t| t.requires_grad()).map(|t| t.numel() as i64).sum()
    }

    /// Samples an action for each env (training; the Random baseline).
    pub fn act(&mut self, obs: &ObsBatch) -> Result<Actions, ObsError> {
        self.act_with(obs, ActMode::Sample)
    }

    /// The most likely action for each env (evaluation). The Random baseline still samples.
    pub fn act_deterministic(&mut self, obs: &ObsBatch) -> Result<Actions, ObsError> {
        self.act_with(obs, ActMode::Greedy)
    }

    pub fn act_with(&mut self, obs: &ObsBatch, mode: ActMode) -> Result<Actions, ObsError> {
        let (inputs, starts) = self.prepare(obs)?;
        let fwd = self.forward(&inputs, starts);
        let actions = self.choose(&fwd, mode);
        self.commit(fwd, obs);
        Ok(actions)
    }

    /// Forgets every env's memory (a new evaluation round).
    pub fn reset(&mut self) {
        let _ = self.hidden.zero_();
        self.force_reset.iter_mut().for_each(|r| *r = false);
    }

    /// Checks the batch, converts it to the stored form, and works out where memory resets.
    pub(crate) fn prepare<'a>(&self, obs: &ObsBatch<'a>) -> Result<(Prepared<'a>, Vec<bool>), ObsError> {
        obs.validate(self.n_envs, (self.spec.height as usize, self.spec.width as usize))?;
        let starts = obs.envs.iter().zip(&self.force_reset).map(|(e, f)| e.episode_start || e.lost || *f).collect();
        let inputs = if self.spec.random() {
            Inputs { rgb: None, depth: None, gesture: None, target: None, pose: None }
        } else {
            self.net.prepare(obs, self.device)
        };
        Ok((Prepared { inputs, _buffers: std::marker::PhantomData }, starts))
    }

    /// The network on one step, from the current memory (reset where `starts`).
    pub(crate) fn forward(&self, x: &Inputs, starts: Vec<bool>) -> Forward {
        let n = self.n_envs;
        if self.spec.random() {
            return Forward {
                logits: vec![0.0; n * action::COUNT],
                values: vec![0.0; n],
                hidden: self.hidden.shallow_clone(),
                starts,
            };
        }
        tch::no_grad(|| {
            let feats = self.net.encode(x).unsqueeze(0);
            let keep: Vec<f32> = starts.iter().map(|s| if *s { 0.0 } else { 1.0 }).collect();
            let keep = Tensor::from_slice(&keep).to_device(self.device).view([1, -1]);
            let (out, hidden) = self.net.recurrent(&feats, &self.hidden, &keep, &[true]);
            let (logits, values) = self.net.heads(&out.squeeze_dim(0));
            let logits =
                Vec::<f32>::try_from(logits.to_kind(Kind::Float).to_device(Device::Cpu).flatten(0, -1)).unwrap();
            let values = Vec::<f32>::try_from(values.to_kind(Kind::Float).to_device(Device::Cpu)).unwrap();
            Forward { logits, values, hidden, starts }
        })
    }

    /// Picks actions from a forward's logits (host side, from the policy's own random stream).
    pub(crate) fn choose(&mut self, fwd: &Forward, mode: ActMode) -> Actions {
        let n = self.n_envs;
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

    /// Makes a forward's memory the current one; lost envs reset at their next message.
    pub(crate) fn commit(&mut self, fwd: Forward, obs: &ObsBatch) {
        self.hidden = fwd.hidden;
        for (r, e) in self.force_reset.iter_mut().zip(obs.envs) {
            *r = e.lost;
        }
    }

    pub(crate) fn hidden(&self) -> &Tensor {
        &self.hidden
    }

    /// Re-syncs derived copies after the variables were overwritten (checkpoint load).
    pub(crate) fn variables_loaded(&self) {
        if let Some(f) = &self.net.frozen {
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
pub(crate) mod tests {
    use super::*;
    pub use crate::bench::random_obs;
    use crate::obs::GestureKind;

    pub fn tiny_config(method: &str) -> RunConfig {
        RunConfig::from_toml(
            &format!(
                "[run]\nmethod = \"{method}\"\n[env]\nwidth = 16\nheight = 16\n\
                 [model]\nencoder = \"small_cnn\"\nhidden = 32\ngru_layers = 1\n[ppo]\nrollout = 8\n"
            ),
            "test.toml",
        )
        .unwrap()
    }

    #[test]
    fn small_cnn_fits_any_frame_size() {
        for (hw, flat) in [((16, 16), 64), ((64, 64), 64 * 16), ((64, 100), 64 * 16), ((224, 224), 64 * 16)] {
            let vs = nn::VarStore::new(Device::Cpu);
            let cnn = SmallCnn::new(&vs.root(), 3, hw, 8);
            assert_eq!(vs.variables()["fc.weight"].size(), vec![8, flat], "{hw:?}");
            let y = tch::no_grad(|| cnn.forward(&Tensor::zeros([2, 3, hw.0, hw.1], (Kind::Float, Device::Cpu))));
            assert_eq!(y.size(), vec![2, 8]);
        }
    }

    #[test]
    fn input_width_follows_the_method() {
        let w = |m: &str| NetSpec::from_config(&tiny_config(m)).input_width();
        assert_eq!(w("vision_only"), 2 * 32);
        assert_eq!(w("vis_sem"), 3 * 32);
        assert_eq!(w("both"), 4 * 32);
        let mut c = tiny_config("both");
        c.model.person_pose = true;
        c.model.depth = false;
        assert_eq!(NetSpec::from_config(&c).input_width(), 4 * 32);
        // faithful: 2048 into the GRU (§4.3.3)
        let f = RunConfig::from_toml("[run]\nmethod = \"both\"\n", "x.toml").unwrap();
        assert_eq!(NetSpec::from_config(&f).input_width(), 2048);
    }

    #[test]
    fn acting_shapes_memory_and_resets() {
        let cfg = tiny_config("both");
        let mut p = Policy::new(&cfg, 3, Device::Cpu).unwrap();
        let mut o = random_obs(3, 16, 1);
        let a = p.act(&o.batch()).unwrap();
        assert_eq!(a.actions.len(), 3);
        assert!(a.actions.iter().all(|a| (0..4).contains(a)));
        assert!(a.log_probs.iter().all(|l| *l <= 0.0 && l.is_finite()));
        // the same observation again, mid-episode: memory changes the values
        o.envs.iter_mut().for_each(|e| e.episode_start = false);
        let b = p.act_deterministic(&o.batch()).unwrap();
        assert_ne!(a.values, b.values);
        // an episode start resets memory: same values as the very first step
        o.envs.iter_mut().for_each(|e| e.episode_start = true);
        let c = p.act_deterministic(&o.batch()).unwrap();
        for (x, y) in a.values.iter().zip(&c.values) {
            assert!((x - y).abs() < 1e-5);
        }
    }

    #[test]
    fn no_gesture_means_zero_gesture_input() {
        let cfg = tiny_config("both");
        let mut p = Policy::new(&cfg, 2, Device::Cpu).unwrap();
        let mut o = random_obs(2, 16, 2);
        o.envs.iter_mut().for_each(|e| e.gesture = GestureKind::None);
        let a = p.act_deterministic(&o.batch()).unwrap();
        o.gesture.iter_mut().for_each(|v| *v = half::f16::from_f32(0.7));
        p.reset();
        let b = p.act_deterministic(&o.batch()).unwrap();
        assert_eq!(a.values, b.values);
    }

    #[test]
    fn sequence_evaluation_matches_step_by_step_acting() {
        // the PPO re-run over whole sequences (fused GRU between resets) must give the values
        // the policy computed step by step when acting
        let cfg = tiny_config("both");
        let mut p = Policy::new(&cfg, 2, Device::Cpu).unwrap();
        let h0 = p.hidden().copy();
        let starts = [[true, true], [false, false], [false, true], [false, false], [true, false]];
        let mut stored = Vec::new();
        let mut acted = Vec::new();
        for (t, s) in starts.iter().enumerate() {
            let mut o = random_obs(2, 16, 10 + t as u64);
            o.envs[0].episode_start = s[0];
            o.envs[1].episode_start = s[1];
            let (x, st) = p.prepare(&o.batch()).unwrap();
            let f = p.forward(&x, st);
            acted.extend(f.values.clone());
            p.commit(f, &o.batch());
            stored.push(x.map(|t| t.copy())); // `o` is dropped at the end of the iteration
        }
        let stack = |get: fn(&Inputs) -> Option<&Tensor>| {
            Some(Tensor::stack(&stored.iter().map(|x| get(x).unwrap().shallow_clone()).collect::<Vec<_>>(), 0))
        };
        let x = Inputs {
            rgb: stack(|x| x.rgb.as_ref()),
            depth: stack(|x| x.depth.as_ref()),
            gesture: stack(|x| x.gesture.as_ref()),
            target: stack(|x| x.target.as_ref()),
            pose: None,
        };
        let keep: Vec<f32> = starts.iter().flatten().map(|s| if *s { 0.0 } else { 1.0 }).collect();
        let keep = Tensor::from_slice(&keep).view([5, 2]);
        let any: Vec<bool> = starts.iter().map(|s| s[0] || s[1]).collect();
        let (_, values) = tch::no_grad(|| p.net.evaluate(&x, &h0, &keep, &any));
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
        let mut p = Policy::new(&cfg, 1, Device::Cpu).unwrap();
        assert!(p.notes().iter().any(|n| n.contains("loaded 100 ResNet-18 tensors")), "{:?}", p.notes());
        assert_eq!(p.spec.input_width(), 2048);
        let vars = p.vs.variables();
        assert!(vars.iter().filter(|(k, _)| k.starts_with("resnet.")).all(|(_, v)| !v.requires_grad()));
        assert_eq!(vars["gru.weight_ih_l1"].size(), vec![3 * 512, 512]);
        assert_eq!(vars["rgb.fc.weight"].size(), vec![512, 64 * 7 * 7]);
        let o = random_obs(1, 224, 3);
        let (x, _) = p.prepare(&o.batch()).unwrap();
        assert_eq!(x.rgb.as_ref().unwrap().size(), vec![1, 512, 7, 7]);
        assert_eq!(x.depth.as_ref().unwrap().size(), vec![1, 512, 7, 7]);
        let a = p.act(&o.batch()).unwrap();
        assert!(a.values[0].is_finite());
        // an Adam over the policy sees only the trainable part
        let opt = crate::optim::Adam::new(&p.vs, 1e-3, 1e-5);
        assert_eq!(opt.state().len() / 2, vars.values().filter(|v| v.requires_grad()).count());
        // 2 × (1×1 convs 74k + FC 1.6M) + gesture FC 4.9M + embedding 19k + GRU 5.5M + heads 1.1M
        assert!((14_000_000..15_000_000).contains(&p.trainable_parameters()), "{}", p.trainable_parameters());
    }

    /// The bf16 copy of the frozen trunk (used on CUDA) follows the f32 weights: checked on the
    /// CPU, which runs bf16 convolutions too.
    #[test]
    fn bf16_trunk_copy_tracks_the_f32_weights() {
        let mut cfg = tiny_config("vis_sem");
        cfg.model.encoder = Encoder::Resnet18;
        cfg.model.resnet_weights = Some("unused.pth".into());
        cfg.env.width = 32;
        cfg.env.height = 32;
        let spec = NetSpec::from_config(&cfg);
        let vs = nn::VarStore::new(Device::Cpu);
        let net = PolicyNet::new(&vs, &spec, true);
        let f = net.frozen.as_ref().unwrap();
        tch::no_grad(|| {
            for (k, mut v) in vs.variables() {
                if k.starts_with("resnet.") && k.ends_with("running_var") {
                    v.copy_(&(Tensor::rand_like(&v) + 0.5));
                }
            }
        });
        f.refresh(&vs);
        let x = Tensor::rand([2, 3, 32, 32], (Kind::Float, Device::Cpu));
        let (full, half) =
            tch::no_grad(|| (f.trunk.forward(&resnet::imagenet_normalize(&x)), f.features(&x).to_kind(Kind::Float)));
        assert_eq!(f.feature_kind(), Kind::BFloat16);
        let err = (&full - &half).abs().max().double_value(&[]);
        let scale = full.abs().max().double_value(&[]);
        assert!(err < 0.05 * scale.max(1.0), "bf16 error {err} vs scale {scale}");
    }

    /// On a GPU machine: the same policy on CUDA and on the CPU agrees. Skipped (with a line
    /// saying so) where there is no GPU.
    #[test]
    fn cuda_policy_agrees_with_cpu() {
        crate::device::load_cuda_backend();
        if !tch::Cuda::is_available() {
            eprintln!("cuda_policy_agrees_with_cpu: skipped, no CUDA device on this machine");
            return;
        }
        let cfg = tiny_config("both");
        let mut cpu = Policy::new(&cfg, 3, Device::Cpu).unwrap();
        let mut gpu = Policy::new(&cfg, 3, Device::Cuda(0)).unwrap();
        tch::no_grad(|| {
            let src = cpu.vs.variables();
            for (k, mut v) in gpu.vs.variables() {
                v.copy_(&src[&k].to_device(Device::Cuda(0)));
            }
        });
        let o = random_obs(3, 16, 4);
        let (a, b) = (cpu.act_deterministic(&o.batch()).unwrap(), gpu.act_deterministic(&o.batch()).unwrap());
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
        let p = Policy::new(&cfg, 1, Device::Cpu).unwrap();
        assert!(p.notes().iter().any(|n| n.contains("NO IMAGENET WEIGHTS")));
        // the trunks are trainable
        assert!(p.vs.variables().iter().any(|(k, v)| k.starts_with("rgb.resnet.layer4") && v.requires_grad()));
    }
}
