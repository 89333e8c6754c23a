//! The run configuration: one TOML file read by the orchestrator, the learner and every worker.
//!
//! Every section has defaults from the dissertation (T4.1, §4.2, §4.3.3) so that a config names
//! only what it changes; unknown keys are errors that name the key's path and the file.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::rooms::Split;

/// The six methods of T4.2.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Uniformly random actions; nothing is learned.
    Random,
    /// RGB and depth only, target-agnostic.
    VisionOnly,
    /// Vision + target category.
    VisSem,
    /// VisSem + the referencing gesture all episode.
    Referencing,
    /// VisSem + an intervention gesture while the robot faces more than 90° away from the target.
    Intervention,
    /// VisSem + intervention when facing away, referencing otherwise.
    Both,
}

impl Method {
    pub const ALL: [Method; 6] =
        [Method::Random, Method::VisionOnly, Method::VisSem, Method::Referencing, Method::Intervention, Method::Both];

    /// What the worker shows the robot.
    pub fn schedule(self) -> GestureSchedule {
        match self {
            Method::Random | Method::Referencing => GestureSchedule::Referencing,
            Method::VisionOnly | Method::VisSem => GestureSchedule::None,
            Method::Intervention => GestureSchedule::Intervention,
            Method::Both => GestureSchedule::Both,
        }
    }

    /// Whether the policy sees the target category.
    pub fn semantic(self) -> bool {
        !matches!(self, Method::VisionOnly)
    }

    /// Whether the policy sees the gesture.
    pub fn gesture(self) -> bool {
        matches!(self, Method::Random | Method::Referencing | Method::Intervention | Method::Both)
    }

    /// Whether a trained policy is shown the referencing gesture (+Referencing; +Both while it
    /// faces the target): what `eval --modes other_gesture` swaps for another room's.
    pub fn shows_referencing(self) -> bool {
        matches!(self, Method::Referencing | Method::Both)
    }

    pub fn label(self) -> &'static str {
        match self {
            Method::Random => "Random",
            Method::VisionOnly => "Vision Only",
            Method::VisSem => "VisSem",
            Method::Referencing => "+Referencing",
            Method::Intervention => "+Intervention",
            Method::Both => "+Both",
        }
    }
}

/// Which gesture the robot perceives at each step (§4.4.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GestureSchedule {
    None,
    Referencing,
    Intervention,
    Both,
}

/// `[run]`: what to train or evaluate on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSection {
    /// Every random stream of the run derives from this.
    #[serde(default = "d_seed")]
    pub seed: u64,
    pub method: Method,
    /// Folder of a dataset made by `orchestrator dataset build`.
    #[serde(default = "d_dataset")]
    pub dataset: PathBuf,
    /// Fold the workers draw episodes from.
    #[serde(default = "d_split")]
    pub split: Split,
    /// Restrict episodes to these rooms ("FloorPlan1", ...); all rooms of the split when empty.
    #[serde(default)]
    pub scenes: Vec<String>,
    /// Use at most this many programs of the split (the first ones of each room, in order).
    #[serde(default)]
    pub max_programs: Option<usize>,
    /// Environment frames to train for (the dissertation trains 5 million).
    #[serde(default = "d_total_frames")]
    pub total_frames: u64,
}

/// `[env]`: the robot and its camera (§3.2.2, §4.2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvConfig {
    /// Environments stepped by one worker process.
    pub envs_per_worker: usize,
    /// Frame width and height in pixels.
    pub width: u32,
    pub height: u32,
    /// Horizontal = vertical field of view, degrees.
    pub fov_deg: f32,
    pub camera_height: f32,
    pub robot_radius: f32,
    pub robot_height: f32,
    /// MoveAhead distance, metres.
    pub move_step: f32,
    /// RotateLeft / RotateRight angle, degrees.
    pub turn_deg: f32,
    /// How frames reach the learner.
    pub frames: FramePath,
}

/// How a worker's frames reach the learner.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FramePath {
    /// Read back to the host and written into the observation's shared memory (every CPU config).
    #[default]
    SharedMemory,
    /// Kept in GPU memory the worker exports and the learner imports (Vulkan external memory;
    /// CUDA on a GPU): no frame crosses the host. The shared memory carries everything else.
    Device,
}

impl Default for EnvConfig {
    fn default() -> Self {
        EnvConfig {
            envs_per_worker: 4,
            width: 224,
            height: 224,
            fov_deg: 90.0,
            camera_height: 1.5,
            robot_radius: 0.3,
            robot_height: 1.5,
            move_step: 0.25,
            turn_deg: 15.0,
            frames: FramePath::SharedMemory,
        }
    }
}

/// `[task]`: success and reward (§4.2, §4.3.2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TaskConfig {
    /// Success needs the robot within this 2D distance of the target centre (metres).
    pub success_distance: f32,
    /// ... and at least this many pixels of the target in view.
    pub min_visible_pixels: u32,
    /// Episode length limit (steps).
    pub max_steps: u32,
    /// Stops allowed before the episode ends; 0 = unlimited (training, ∞ in T4.4).
    pub max_stops: u32,
    pub reward_success: f32,
    /// Subtracted every step.
    pub step_penalty: f32,
    /// Subtracted for a blocked move.
    pub collision_penalty: f32,
    /// Subtracted for a stop that does not succeed.
    pub wrong_stop_penalty: f32,
    /// Reward per metre of geodesic progress toward the success region (negative when moving
    /// away). 0 in the dissertation (§4.3.2); the tiny CPU configs use a little of it so that a
    /// 20-minute run on two cores learns (a standard shaping of embodied navigation).
    pub progress_reward: f32,
    /// Intervention gestures show while heading and target bearing differ by more than this.
    pub intervention_angle_deg: f32,
    /// Distance-to-success threshold of DTS (the dissertation writes 1.5 m).
    pub dts_threshold: f32,
    /// A check, not a setting to train with: each program shows the referencing gesture of the
    /// program this many places on in its split (0: its own). A policy that reads where the
    /// gesture points loses what it gained from it; one that reads only that a gesture is shown
    /// does not.
    pub gesture_shift: u64,
}

impl Default for TaskConfig {
    fn default() -> Self {
        TaskConfig {
            success_distance: 1.0,
            min_visible_pixels: 1,
            max_steps: 100,
            max_stops: 0,
            reward_success: 1.0,
            step_penalty: 0.001,
            collision_penalty: 0.005,
            wrong_stop_penalty: 0.01,
            progress_reward: 0.0,
            intervention_angle_deg: 90.0,
            dts_threshold: 1.5,
            gesture_shift: 0,
        }
    }
}

/// Visual encoder of the policy.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Encoder {
    /// Frozen ResNet-18 conv5 → 1×1 convs → FC 512 (§4.3.3).
    Resnet18,
    /// A small trained CNN for CPU runs.
    SmallCnn,
    /// The early-fusion RGB-D encoder of `orchestrator encoder pretrain`, frozen: its features
    /// are computed once when acting and stored in the rollout (CPU runs).
    Pretrained,
}

/// How the robot perceives a gesture: what the gesture network reads, 100 frames of it. Other
/// readings were tried and left the product (docs/experiments names the commit that has them).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GestureInput {
    /// The 95 muscle values of the humanoid, in the person's own frame (§4.3.3).
    #[default]
    Muscles,
}

/// How the gesture network reads a gesture's 100 frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GestureNetwork {
    /// The frames flattened into one fully connected layer (§4.3.3: 9,500 → 512 for the muscles).
    #[default]
    Flat,
    /// Beyond the dissertation: the flat layer beside one small network shared by every frame,
    /// each giving half the feature. The shared one reads the gesture alone, once per distinct
    /// gesture, pools it over time (mean and max), and the person's pose (`model.person_pose`)
    /// joins after the pooling, turning what was pooled by their facing: a pose held in any
    /// frames is read by the same weights, and a pointing says where to go from where the robot
    /// stands.
    FlatAndTurned,
}

/// `[model]`: the network (§4.3.3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    pub encoder: Encoder,
    /// torchvision ResNet-18 checkpoint (ImageNet weights, or the label-free trunk of `orchestrator
    /// encoder pretrain --trunk resnet18`); without it the encoder is trained.
    pub resnet_weights: Option<PathBuf>,
    /// Weights of the pretrained encoder (`encoder = "pretrained"`), as `orchestrator encoder
    /// pretrain` writes them; relative to the working directory.
    pub encoder_weights: Option<PathBuf>,
    /// Inputs; the method decides semantic and gesture, these switch the visual ones (T4.7).
    pub rgb: bool,
    pub depth: bool,
    /// Feed the person's pose relative to the robot (the released code did; the text does not).
    pub person_pose: bool,
    /// How the gesture is perceived (`muscles`: the dissertation's, the only one).
    pub gesture_input: GestureInput,
    /// How the gesture's frames are read (`flat`: the dissertation; `flat_and_turned`: beyond it).
    pub gesture_network: GestureNetwork,
    /// Width of every feature and hidden layer.
    pub hidden: i64,
    /// GRU layers (the dissertation: 2; the released code: 1).
    pub gru_layers: i64,
}

impl Default for ModelConfig {
    fn default() -> Self {
        ModelConfig {
            encoder: Encoder::Resnet18,
            resnet_weights: None,
            encoder_weights: None,
            rgb: true,
            depth: true,
            person_pose: false,
            gesture_input: GestureInput::Muscles,
            gesture_network: GestureNetwork::Flat,
            hidden: 512,
            gru_layers: 2,
        }
    }
}

/// `[ppo]`: T4.1 and §4.3.2.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PpoConfig {
    /// Steps per environment per rollout (T4.1: 128).
    pub rollout: usize,
    /// Passes over each rollout (T4.1: 4).
    pub epochs: usize,
    /// Minibatches per epoch (whole environments per minibatch, so the GRU sees full sequences).
    pub minibatches: usize,
    /// Adam learning rate, decayed linearly to 0 over `total_frames` (T4.1: 3e-4).
    pub lr: f64,
    /// Clipping parameter ε of Eq. 4.2 (T4.1: 0.2).
    pub clip: f64,
    /// Discount factor γ (T4.1: 0.99).
    pub gamma: f64,
    /// GAE parameter λ of Eq. 4.3 (T4.1: 0.99).
    pub gae_lambda: f64,
    /// Maximum gradient norm (§4.3.2: 0.5).
    pub max_grad_norm: f64,
    /// Weight of the value loss (not given in the dissertation; the usual 0.5).
    pub value_coef: f64,
    /// Weight of the entropy bonus (not given in the dissertation; 0.01).
    pub entropy_coef: f64,
    /// Clip the value loss around the rollout's values with `clip` (as CleanRL's `clip_vloss`).
    pub clip_value_loss: bool,
    /// On CUDA, run the frozen ResNet-18 in bf16 and keep its features in bf16 (the trained
    /// layers stay f32).
    pub mixed_precision: bool,
    /// Acting rounds taken by this many groups of workers in turn (contiguous blocks), so that
    /// one group renders while the next is inferred — a GPU setting (1: one round for all). Envs,
    /// actions and what is learned are those of one round for all; a rollout's last step is
    /// still one round for all, as the update needs every env's next observation.
    pub env_groups: usize,
    /// Learn each rollout on a thread, on a copy of the network, while the next one is collected
    /// with the weights before it (policy lag 1) — a GPU setting, for where the update and acting
    /// each leave the other room; on two CPU cores they share the cores and it gains nothing.
    pub overlap_update: bool,
}

impl Default for PpoConfig {
    fn default() -> Self {
        PpoConfig {
            rollout: 128,
            epochs: 4,
            minibatches: 1,
            lr: 3e-4,
            clip: 0.2,
            gamma: 0.99,
            gae_lambda: 0.99,
            max_grad_norm: 0.5,
            value_coef: 0.5,
            entropy_coef: 0.01,
            clip_value_loss: true,
            mixed_precision: true,
            env_groups: 1,
            overlap_update: false,
        }
    }
}

/// `[checkpoint]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CheckpointConfig {
    /// Write a checkpoint every this many updates (and on Ctrl-C).
    pub every_updates: u64,
    /// Keep this many most recent checkpoints.
    pub keep: usize,
}

impl Default for CheckpointConfig {
    fn default() -> Self {
        CheckpointConfig { every_updates: 10, keep: 3 }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Device {
    /// CUDA when a GPU is there, else CPU.
    #[default]
    Auto,
    Cpu,
    Cuda,
}

/// The whole file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    pub run: RunSection,
    #[serde(default)]
    pub env: EnvConfig,
    #[serde(default)]
    pub task: TaskConfig,
    #[serde(default)]
    pub model: ModelConfig,
    #[serde(default)]
    pub ppo: PpoConfig,
    #[serde(default)]
    pub checkpoint: CheckpointConfig,
    #[serde(default)]
    pub device: Device,
}

fn d_seed() -> u64 {
    1
}
fn d_dataset() -> PathBuf {
    PathBuf::from("data/gond")
}
fn d_split() -> Split {
    Split::Train
}
fn d_total_frames() -> u64 {
    5_000_000
}

/// A config that cannot be used: file, field path, reason.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {field}: {message}")]
pub struct ConfigError {
    pub file: String,
    pub field: String,
    pub message: String,
}

impl RunConfig {
    pub fn load(path: &Path) -> Result<RunConfig, ConfigError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
            file: file.clone(),
            field: "(file)".into(),
            message: e.to_string(),
        })?;
        RunConfig::from_toml(&text, &file)
    }

    pub fn from_toml(text: &str, file: &str) -> Result<RunConfig, ConfigError> {
        let de = toml::Deserializer::parse(text).map_err(|e| ConfigError {
            file: file.into(),
            field: "(syntax)".into(),
            message: e.to_string(),
        })?;
        let cfg: RunConfig = serde_path_to_error::deserialize(de).map_err(|e| ConfigError {
            file: file.into(),
            field: e.path().to_string(),
            message: e.inner().message().to_string(),
        })?;
        cfg.validate().map_err(|(field, message)| ConfigError { file: file.into(), field, message })?;
        Ok(cfg)
    }

    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("config serialises")
    }

    /// This config with `section.key=value` overrides applied in order (`--set`; the value in
    /// TOML syntax, a bare word taken as a string), each checked as a config file is; an
    /// error names the override and its key.
    pub fn with_overrides(&self, sets: &[String]) -> Result<RunConfig, ConfigError> {
        let mut table: toml::Table = toml::from_str(&self.to_toml()).expect("a config reads its own TOML");
        let mut cfg = self.clone();
        for s in sets {
            let fail =
                |field: &str, message: String| ConfigError { file: format!("--set {s}"), field: field.into(), message };
            let (key, raw) =
                s.split_once('=').ok_or_else(|| fail("(syntax)", "expected KEY=VALUE, e.g. ppo.lr=1e-4".into()))?;
            let key = key.trim();
            let value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
                .ok()
                .and_then(|mut t| t.remove("v"))
                .unwrap_or_else(|| toml::Value::String(raw.trim().to_string()));
            let (path, last) = match key.rsplit_once('.') {
                Some((p, l)) => (p.split('.').collect::<Vec<_>>(), l),
                None => (Vec::new(), key),
            };
            let mut t = &mut table;
            for part in path {
                t = t
                    .entry(part)
                    .or_insert_with(|| toml::Value::Table(Default::default()))
                    .as_table_mut()
                    .ok_or_else(|| fail(key, format!("`{part}` is a value, not a section")))?;
            }
            t.insert(last.to_string(), value);
            let text = toml::to_string(&table).expect("a TOML table serialises");
            cfg = RunConfig::from_toml(&text, &format!("--set {s}")).map_err(|e| fail(key, e.message))?;
        }
        Ok(cfg)
    }

    /// Range checks serde cannot express.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let e = |f: &str, m: String| Err((f.to_string(), m));
        let env = &self.env;
        if !(1..=64).contains(&env.envs_per_worker) {
            return e("env.envs_per_worker", format!("must be 1..=64, got {}", env.envs_per_worker));
        }
        for (f, v) in [("env.width", env.width), ("env.height", env.height)] {
            if !(16..=1024).contains(&v) {
                return e(f, format!("must be 16..=1024 pixels, got {v}"));
            }
        }
        if !(10.0..=170.0).contains(&env.fov_deg) {
            return e("env.fov_deg", format!("must be 10..=170 degrees, got {}", env.fov_deg));
        }
        if !(env.move_step > 0.0 && env.turn_deg > 0.0 && env.robot_radius > 0.0) {
            return e("env", "move_step, turn_deg and robot_radius must be positive".into());
        }
        if self.task.max_steps == 0 {
            return e("task.max_steps", "must be at least 1".into());
        }
        if self.task.success_distance <= 0.0 {
            return e("task.success_distance", "must be positive".into());
        }
        let p = &self.ppo;
        if p.rollout == 0 || p.epochs == 0 || p.minibatches == 0 || p.env_groups == 0 {
            return e("ppo", "rollout, epochs, minibatches and env_groups must be at least 1".into());
        }
        if !(p.lr > 0.0 && p.lr < 1.0) {
            return e("ppo.lr", format!("must be in (0, 1), got {}", p.lr));
        }
        if !(0.0..=1.0).contains(&p.gamma) || !(0.0..=1.0).contains(&p.gae_lambda) {
            return e("ppo.gamma", "gamma and gae_lambda must be in [0, 1]".into());
        }
        if !(p.clip > 0.0 && p.clip < 1.0) {
            return e("ppo.clip", format!("must be in (0, 1), got {}", p.clip));
        }
        if !(p.max_grad_norm > 0.0) {
            return e("ppo.max_grad_norm", format!("must be positive, got {}", p.max_grad_norm));
        }
        for (f, v) in [("ppo.value_coef", p.value_coef), ("ppo.entropy_coef", p.entropy_coef)] {
            if !(v >= 0.0 && v.is_finite()) {
                return e(f, format!("must be zero or positive, got {v}"));
            }
        }
        if self.run.total_frames == 0 {
            return e("run.total_frames", "must be at least 1 frame".into());
        }
        if self.checkpoint.every_updates == 0 {
            return e("checkpoint.every_updates", "must be at least 1".into());
        }
        if self.model.hidden <= 0 || self.model.gru_layers <= 0 {
            return e("model.hidden", "hidden and gru_layers must be positive".into());
        }
        if !self.model.rgb && !self.model.depth && self.run.method != Method::Random {
            // blind training is allowed only through eval's blind mode
            return e("model.rgb", "at least one of model.rgb and model.depth must be on".into());
        }
        if self.model.encoder == Encoder::Pretrained && self.model.encoder_weights.is_none() {
            return e(
                "model.encoder_weights",
                "encoder = \"pretrained\" needs the weights file (make one with `orchestrator encoder pretrain`)"
                    .into(),
            );
        }
        for (i, s) in self.run.scenes.iter().enumerate() {
            if crate::rooms::SceneId::parse(s).is_none() {
                return e(&format!("run.scenes[{i}]"), format!("`{s}` is not a room name like FloorPlan201"));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minimal_config_takes_defaults_from_t41() {
        let c = RunConfig::from_toml("[run]\nmethod = \"both\"\n", "x.toml").unwrap();
        assert_eq!(c.ppo.rollout, 128);
        assert_eq!(c.ppo.epochs, 4);
        assert_eq!(c.ppo.lr, 3e-4);
        assert_eq!(c.ppo.clip, 0.2);
        assert_eq!(c.ppo.gamma, 0.99);
        assert_eq!(c.ppo.gae_lambda, 0.99);
        assert_eq!(c.ppo.max_grad_norm, 0.5);
        assert_eq!(c.task.max_steps, 100);
        assert_eq!(c.env.width, 224);
        assert_eq!(c.run.method.schedule(), GestureSchedule::Both);
    }

    #[test]
    fn overrides_apply_in_order_and_a_bad_one_names_its_key() {
        let c = RunConfig::from_toml("[run]\nmethod = \"both\"\n", "x.toml").unwrap();
        let sets = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let o =
            c.with_overrides(&sets(&["ppo.lr=1e-4", "env.width=96", "run.method=vis_sem", "env.width = 80"])).unwrap();
        assert_eq!((o.ppo.lr, o.env.width, o.run.method), (1e-4, 80, Method::VisSem));
        assert_eq!(o.ppo.rollout, c.ppo.rollout, "the rest untouched");
        assert_eq!(c.model.gesture_input, GestureInput::Muscles, "the dissertation's by default");
        let m = c.with_overrides(&sets(&["model.gesture_input=muscles"])).unwrap();
        assert_eq!(m.model.gesture_input, GestureInput::Muscles);
        assert_eq!(c.model.gesture_network, GestureNetwork::Flat, "the dissertation's by default");
        let t = c.with_overrides(&sets(&["model.gesture_network=flat_and_turned"])).unwrap();
        assert_eq!(t.model.gesture_network, GestureNetwork::FlatAndTurned);
        for (bad, says) in [
            ("ppo.lrr=1", "ppo.lrr"),
            ("ppo.clip=-5", "ppo.clip"),
            ("env.width", "KEY=VALUE"),
            ("env.width=abc", "env.width"),
            ("model.gesture_input=skeleton", "model.gesture_input"),
            ("model.gesture_input=keypoints", "model.gesture_input"),
            ("model.gesture_network=lstm", "model.gesture_network"),
            ("model.gesture_network=per_frame", "model.gesture_network"),
        ] {
            let err = c.with_overrides(&sets(&[bad])).unwrap_err().to_string();
            assert!(err.contains(says) && !err.contains('\n'), "{bad}: {err}");
        }
    }

    #[test]
    fn typo_names_the_field_and_file() {
        let err =
            RunConfig::from_toml("[run]\nmethod = \"both\"\n[ppo]\nlearning_rate = 1.0\n", "cfg/x.toml").unwrap_err();
        let s = err.to_string();
        assert!(s.contains("cfg/x.toml") && s.contains("learning_rate"), "{s}");
        let err = RunConfig::from_toml("[run]\nmethod = \"telepathy\"\n", "x.toml").unwrap_err();
        assert!(err.to_string().contains("run.method"), "{err}");
        let err = RunConfig::from_toml("[run]\nmethod = \"both\"\n[env]\nwidth = 4\n", "x.toml").unwrap_err();
        assert!(err.to_string().contains("env.width"), "{err}");
        let err = RunConfig::from_toml("[run]\nmethod = \"both\"\n[model]\nencoder = \"pretrained\"\n", "x.toml")
            .unwrap_err();
        assert!(err.to_string().contains("model.encoder_weights"), "{err}");
        for (toml, field) in [
            ("[run]\nmethod = \"both\"\ntotal_frames = 0\n", "run.total_frames"),
            ("[run]\nmethod = \"both\"\n[ppo]\nclip = -5\n", "ppo.clip"),
            ("[run]\nmethod = \"both\"\n[ppo]\nmax_grad_norm = 0\n", "ppo.max_grad_norm"),
        ] {
            let err = RunConfig::from_toml(toml, "x.toml").unwrap_err().to_string();
            assert!(err.contains("x.toml") && err.contains(field), "{toml}: {err}");
        }
    }

    #[test]
    fn each_config_folder_reads_every_gesture_one_way() {
        // A study compares methods by what they are shown; how a gesture is read, and whether the
        // person's pose comes with it, is the folder's choice, the same for every gesture method.
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
        for folder in std::fs::read_dir(&root).unwrap() {
            let mut readings = Vec::new();
            for file in std::fs::read_dir(folder.unwrap().path()).unwrap() {
                let path = file.unwrap().path();
                let c = RunConfig::load(&path).unwrap();
                let m = &c.model;
                if c.run.method == Method::Random {
                    continue; // acts without reading anything
                }
                if c.run.method.gesture() {
                    readings.push(((m.gesture_input, m.gesture_network, m.person_pose), path));
                } else {
                    assert!(!m.person_pose, "{}: the person's pose comes with a gesture", path.display());
                }
            }
            for (reading, path) in &readings {
                assert_eq!(*reading, readings[0].0, "{} against {}", path.display(), readings[0].1.display());
            }
        }
    }

    #[test]
    fn round_trips_through_toml() {
        let c = RunConfig::from_toml("[run]\nmethod = \"vis_sem\"\nscenes = [\"FloorPlan1\"]\n", "x.toml").unwrap();
        let back = RunConfig::from_toml(&c.to_toml(), "y.toml").unwrap();
        assert_eq!(c, back);
    }
}
