//! The network's building blocks: the visual encoders (a head after the frozen ResNet trunk, a
//! ResNet trained end to end, a small CNN for CPU runs, the pretrained RGB-D encoder), the frozen
//! trunk shared by RGB and depth with its bf16 copy, and the MLP of the actor and critic heads.
//! How they are wired is `crate::net::network`.

use tch::{Kind, Tensor, nn};

use crate::encoder::net::{FEATURE_CHANNELS, RgbdEncoder, STRIDE, encoder_input};
use crate::inputs::{depth_unit, rgb_unit};
use crate::net::resnet::{self, CONV5_CHANNELS, Resnet18};

/// Images in 0..1 with 1 or 3 channels → ImageNet-normalised 3 channels.
pub(crate) fn resnet_input(x: &Tensor) -> Tensor {
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
pub(crate) struct ConvHead {
    reduce1: nn::Conv2D,
    reduce2: nn::Conv2D,
    fc: nn::Linear,
}

impl ConvHead {
    pub(crate) fn new(p: &nn::Path, side: (i64, i64), hidden: i64) -> ConvHead {
        let c = nn::ConvConfig::default();
        ConvHead {
            reduce1: nn::conv2d(p / "reduce1", CONV5_CHANNELS, 128, 1, c),
            reduce2: nn::conv2d(p / "reduce2", 128, 64, 1, c),
            fc: nn::linear(p / "fc", 64 * side.0 * side.1, hidden, Default::default()),
        }
    }

    pub(crate) fn forward(&self, conv5: &Tensor) -> Tensor {
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
pub(crate) struct SmallCnn {
    convs: [nn::Conv2D; 3],
    pool: Option<[i64; 2]>,
    fc: nn::Linear,
}

impl SmallCnn {
    pub(crate) fn new(p: &nn::Path, c_in: i64, hw: (i64, i64), hidden: i64) -> SmallCnn {
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

    pub(crate) fn forward(&self, x: &Tensor) -> Tensor {
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
pub(crate) enum Visual {
    /// After the shared frozen trunk: reads stored conv5 features.
    Frozen(ConvHead),
    /// Its own ResNet-18, trained from random weights.
    Resnet(Resnet18, ConvHead),
    SmallCnn(SmallCnn),
}

impl Visual {
    /// `x`: stored form, `[B, ..]`; `depth`: whether it is a depth input.
    pub(crate) fn forward(&self, x: &Tensor, depth: bool) -> Tensor {
        let unit = || if depth { depth_unit(x) } else { rgb_unit(x) };
        match self {
            Visual::Frozen(head) => head.forward(x),
            Visual::Resnet(trunk, head) => head.forward(&trunk.forward(&resnet_input(&unit()))),
            Visual::SmallCnn(cnn) => cnn.forward(&unit()),
        }
    }
}

/// The pretrained early-fusion RGB-D encoder (`crate::encoder`), frozen, and the trained head on
/// its stored features: a 1×1 convolution to a few channels, flatten, FC. One visual feature for
/// RGB and depth; a run without one of them (T4.7) zeroes its input channels, as the
/// pretraining did in some frames.
#[derive(Debug)]
pub(crate) struct Pretrained {
    trunk: RgbdEncoder,
    /// `[1, 4, 1, 1]` of 0/1, when a modality is off.
    channels: Option<Tensor>,
    reduce: nn::Conv2D,
    fc: nn::Linear,
}

/// Channels of the head's 1×1 reduction (64 → 16: an 8×8 map then feeds a 1,024-wide FC).
const PRETRAINED_HEAD_CHANNELS: i64 = 16;

impl Pretrained {
    /// The trunk under `encoder.` in `vs` (left out of training: no gradients; its weights come
    /// from `crate::encoder::load_weights`), the head under `visual.`.
    pub(crate) fn new(vs: &nn::VarStore, hw: (i64, i64), rgb: bool, depth: bool, hidden: i64) -> Pretrained {
        let root = vs.root();
        let trunk = RgbdEncoder::new(&(&root / "encoder"));
        for (name, v) in vs.variables() {
            if name.starts_with("encoder.") {
                let _ = v.set_requires_grad(false);
            }
        }
        let on = |b: bool| if b { 1f32 } else { 0.0 };
        let channels = (!(rgb && depth)).then(|| {
            Tensor::from_slice(&[on(rgb), on(rgb), on(rgb), on(depth)]).view([1, 4, 1, 1]).to_device(vs.device())
        });
        let p = &root / "visual";
        let cells = (hw.0 / STRIDE) * (hw.1 / STRIDE);
        Pretrained {
            trunk,
            channels,
            reduce: nn::conv2d(&p / "reduce", FEATURE_CHANNELS, PRETRAINED_HEAD_CHANNELS, 1, Default::default()),
            fc: nn::linear(&p / "fc", PRETRAINED_HEAD_CHANNELS * cells, hidden, Default::default()),
        }
    }

    /// The stored form: frames (RGB u8 `[B, H, W, 3]`, depth Int16 `[B, H, W]`) → trunk
    /// features f32 `[B, 64, H/8, W/8]`, without gradients.
    pub(crate) fn features(&self, rgb: &Tensor, depth: &Tensor) -> Tensor {
        tch::no_grad(|| {
            let x = encoder_input(rgb, depth);
            let x = match &self.channels {
                Some(m) => x * m,
                None => x,
            };
            self.trunk.forward(&x)
        })
    }

    /// Stored features `[B, 64, h, w]` → `[B, hidden]`.
    pub(crate) fn forward(&self, features: &Tensor) -> Tensor {
        features.apply(&self.reduce).relu().flatten(1, -1).apply(&self.fc).relu()
    }
}

/// The frozen ImageNet trunk shared by RGB and depth, and its bf16 copy for CUDA.
#[derive(Debug)]
pub(crate) struct FrozenTrunk {
    trunk: Resnet18,
    bf16: Option<(nn::VarStore, Resnet18)>,
}

impl FrozenTrunk {
    /// The trunk under `resnet.` in `vs`, left out of training (no gradients); `bf16`: with a
    /// bf16 copy in a var store of its own, which [`FrozenTrunk::refresh`] keeps in step.
    pub(crate) fn new(vs: &nn::VarStore, bf16: bool) -> FrozenTrunk {
        let trunk = Resnet18::new(&(vs.root() / "resnet"));
        let bf16 = bf16.then(|| {
            let mut half = nn::VarStore::new(vs.device());
            let t = Resnet18::folded(&(half.root() / "resnet"));
            bf16_channels_last(&mut half);
            half.freeze();
            (half, t)
        });
        for (name, v) in vs.variables() {
            if name.starts_with("resnet.") {
                let _ = v.set_requires_grad(false);
            }
        }
        let trunk = FrozenTrunk { trunk, bf16 };
        trunk.refresh(vs);
        trunk
    }

    /// conv5 features of images in 0..1, `[B, C, H, W]`, in the kind the rollout stores.
    pub(crate) fn features(&self, x: &Tensor) -> Tensor {
        let x = resnet_input(x);
        match &self.bf16 {
            Some((_, t)) => t.forward(&channels_last(&x.to_kind(Kind::BFloat16))),
            None => self.trunk.forward(&x),
        }
    }

    /// How far the bf16 copy's features (folded; fused on a GPU) are from the f32 trunk's with
    /// its batch norms on `x`: the largest difference over the largest value (at least 1). None
    /// without a bf16 copy.
    pub(crate) fn bf16_error(&self, x: &Tensor) -> Option<f64> {
        self.bf16.as_ref()?;
        let (full, half) = tch::no_grad(|| {
            (self.trunk.forward(&resnet_input(x)).to_kind(Kind::Float), self.features(x).to_kind(Kind::Float))
        });
        let scale = full.abs().max().double_value(&[]).max(1.0);
        Some((&full - &half).abs().max().double_value(&[]) / scale)
    }

    /// Moves every batch norm's statistics and affine map away from their initial values (drawn
    /// from torch's generator), then refreshes the bf16 copy: what checks of the fold need, since
    /// at their initial values (mean 0, variance 1, some scales 0) a wrong fold can pass.
    pub(crate) fn vary_batch_norms(&self, vs: &nn::VarStore) {
        tch::no_grad(|| {
            for (k, mut v) in vs.variables() {
                if !k.starts_with("resnet.") || v.dim() != 1 {
                    continue;
                }
                let r = Tensor::rand_like(&v);
                if k.ends_with("running_var") {
                    v.copy_(&(r + 0.5));
                } else if k.ends_with("weight") {
                    v.copy_(&(r * 0.5 + 0.75));
                } else {
                    v.copy_(&((r - 0.5) * 0.2));
                }
            }
        });
        self.refresh(vs);
    }

    pub(crate) fn feature_kind(&self) -> Kind {
        if self.bf16.is_some() { Kind::BFloat16 } else { Kind::Float }
    }

    /// Makes the bf16 copy from the (f32) trunk's weights, its batch norms folded into its
    /// convolutions; after loading weights.
    pub(crate) fn refresh(&self, vs: &nn::VarStore) {
        if let Some((half, _)) = &self.bf16 {
            let src = vs.variables();
            tch::no_grad(|| {
                for (name, mut dst) in half.variables() {
                    dst.copy_(&resnet::fold_batch_norms(&src, &name).to_kind(dst.kind()));
                }
            });
        }
    }
}

/// `x` `[B, C, H, W]` with its channels innermost in memory (torch's channels-last format): the
/// layout in which bf16 convolutions run on the GPU's tensor cores without a transposition around
/// every layer. Same shape and values.
pub(crate) fn channels_last(x: &Tensor) -> Tensor {
    x.permute([0, 2, 3, 1]).contiguous().permute([0, 3, 1, 2])
}

/// Makes every variable of `vs` bf16, its convolution weights channels-last: how a frozen trunk
/// runs on the GPU's tensor cores.
pub(crate) fn bf16_channels_last(vs: &mut nn::VarStore) {
    vs.bfloat16();
    for (_, mut v) in vs.variables() {
        if v.dim() == 4 {
            v.set_data(&channels_last(&v));
        }
    }
}

/// The actor and critic heads: a plain MLP.
#[derive(Debug)]
pub(crate) struct Mlp {
    layers: Vec<nn::Linear>,
}

impl Mlp {
    /// `depth` hidden layers of `width` with ReLU, then a linear output with gain `out_gain`.
    pub(crate) fn new(p: &nn::Path, input: i64, width: i64, depth: usize, out: i64, out_gain: f64) -> Mlp {
        let mut layers = Vec::new();
        let mut i = input;
        for l in 0..depth {
            layers.push(linear(p / format!("{l}"), i, width, 2f64.sqrt()));
            i = width;
        }
        layers.push(linear(p / "out", i, out, out_gain));
        Mlp { layers }
    }

    pub(crate) fn forward(&self, x: &Tensor) -> Tensor {
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

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

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

    /// The bf16 copy of the frozen trunk (used on CUDA) follows the f32 weights, its batch norms
    /// folded in, in channels-last layout: checked on the CPU, which runs bf16 convolutions too.
    #[test]
    fn bf16_trunk_copy_tracks_the_f32_weights() {
        let vs = nn::VarStore::new(Device::Cpu);
        // every draw from torch's one generator under `seeded`: tests run side by side
        let f = crate::device::seeded(7, || FrozenTrunk::new(&vs, true));
        crate::device::seeded(8, || f.vary_batch_norms(&vs));
        let x = crate::device::seeded(6, || Tensor::rand([2, 3, 32, 32], (Kind::Float, Device::Cpu)));
        assert_eq!(f.feature_kind(), Kind::BFloat16);
        // its convolution weights stay channels-last through the refresh (the tensor cores' layout)
        let half_vars = f.bf16.as_ref().unwrap().0.variables();
        assert!(half_vars.values().filter(|v| v.dim() == 4).all(|v| v.stride()[1] == 1));
        let err = f.bf16_error(&x).unwrap();
        assert!(err < 0.05, "bf16 error {err} of the scale");
    }
}
