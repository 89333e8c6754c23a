//! What the network looks like for a run ([`NetSpec`]): which inputs the method and config switch
//! on, which visual encoder, the frame size and the widths. Everything that builds, stores or
//! checks a network reads it from here.

use farm::config::{Encoder, GestureNetwork, Method, RunConfig};

/// What the network looks like for a run: which inputs, which encoder, how wide.
#[derive(Clone, Debug, PartialEq)]
pub struct NetSpec {
    pub method: Method,
    pub encoder: Encoder,
    /// ResNet-18 with supplied weights (ImageNet, or the label-free trunk of `encoder pretrain --trunk
    /// resnet18`), frozen. False: every encoder is trained.
    pub frozen: bool,
    pub rgb: bool,
    pub depth: bool,
    pub gesture: bool,
    /// How the gesture's 100 frames of 95 muscles are read (§4.3.3's flat layer, or beside one
    /// shared per frame).
    pub gesture_network: GestureNetwork,
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
            gesture_network: m.gesture_network,
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

    /// One visual feature vector for RGB and depth together (the pretrained early-fusion
    /// encoder), instead of one per modality.
    pub fn fused(&self) -> bool {
        self.encoder == Encoder::Pretrained
    }

    /// The gesture network reads the person's pose after pooling its frames (`flat_and_turned`):
    /// an arm's direction in the person's own frame (the muscles) becomes one in the robot's only
    /// through their facing.
    pub fn gesture_reads_pose(&self) -> bool {
        self.gesture && self.pose && self.gesture_network == GestureNetwork::FlatAndTurned
    }

    /// Values of the pose the gesture network reads (right, forward, cos and sin of the facing)
    /// where [`NetSpec::gesture_reads_pose`], else none.
    pub fn gesture_pose_dims(&self) -> i64 {
        if self.gesture_reads_pose() { crate::inputs::FRAME_POSE_DIMS } else { 0 }
    }

    /// Width of the concatenated features fed to the GRU.
    pub fn input_width(&self) -> i64 {
        let visual = if self.fused() {
            usize::from(self.rgb || self.depth)
        } else {
            usize::from(self.rgb) + usize::from(self.depth)
        };
        let n = visual + [self.gesture, self.semantic, self.pose].iter().filter(|b| **b).count();
        self.hidden * n as i64
    }

    /// The gesture input's name in logs, with its network when not the flat one.
    fn gesture_name(&self) -> String {
        match (self.gesture_network, self.gesture_reads_pose()) {
            (GestureNetwork::Flat, _) => "gesture".into(),
            (GestureNetwork::FlatAndTurned, false) => "gesture read flat and per frame".into(),
            (GestureNetwork::FlatAndTurned, true) => {
                "gesture read flat and per frame turned by the person's pose".into()
            }
        }
    }

    /// One line for logs.
    pub fn describe(&self) -> String {
        let mut inputs = Vec::new();
        for (on, name) in [
            (self.rgb, "rgb".to_string()),
            (self.depth, "depth".to_string()),
            (self.gesture, self.gesture_name()),
            (self.semantic, "target".to_string()),
            (self.pose, "person-pose".to_string()),
        ] {
            if on {
                inputs.push(name);
            }
        }
        let enc = match (self.encoder, self.frozen) {
            (Encoder::Resnet18, true) => "ResNet-18 (frozen, model.resnet_weights)",
            (Encoder::Resnet18, false) => "ResNet-18 (TRAINED from random weights)",
            (Encoder::SmallCnn, _) => "small CNN (trained)",
            (Encoder::Pretrained, _) => "pretrained RGB-D encoder (frozen, one for both)",
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

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A tiny network for tests: 16×16 frames, small CNN, hidden 32, one GRU layer, rollout 8.
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
    fn input_width_follows_the_method() {
        let w = |m: &str| NetSpec::from_config(&tiny_config(m)).input_width();
        assert_eq!(w("vision_only"), 2 * 32);
        assert_eq!(w("vis_sem"), 3 * 32);
        assert_eq!(w("both"), 4 * 32);
        let mut c = tiny_config("both");
        c.model.person_pose = true;
        c.model.depth = false;
        assert_eq!(NetSpec::from_config(&c).input_width(), 4 * 32);
        // the pretrained encoder: one visual feature for RGB and depth, and for either alone (T4.7)
        let mut c = tiny_config("both");
        c.model.encoder = farm::config::Encoder::Pretrained;
        assert_eq!(NetSpec::from_config(&c).input_width(), 3 * 32);
        c.model.rgb = false;
        assert_eq!(NetSpec::from_config(&c).input_width(), 3 * 32);
        // faithful: 2048 into the GRU (§4.3.3)
        let f = RunConfig::from_toml("[run]\nmethod = \"both\"\n", "x.toml").unwrap();
        assert_eq!(NetSpec::from_config(&f).input_width(), 2048);
    }

    #[test]
    fn logs_name_how_the_gesture_is_read() {
        let name = |network, pose| {
            let mut c = tiny_config("both");
            (c.model.gesture_network, c.model.person_pose) = (network, pose);
            NetSpec::from_config(&c).gesture_name()
        };
        assert_eq!(name(GestureNetwork::Flat, true), "gesture");
        assert_eq!(name(GestureNetwork::FlatAndTurned, false), "gesture read flat and per frame");
        let turned = name(GestureNetwork::FlatAndTurned, true);
        assert_eq!(turned, "gesture read flat and per frame turned by the person's pose");
    }
}
