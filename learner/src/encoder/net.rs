//! The early-fusion RGB-D encoder: RGB and depth enter as one 4-channel image, so acting runs
//! one small network instead of two, and its output is a feature map the rollout can store.
//!
//! ```text
//! [B, 4, H, W] in 0..1 (R, G, B, depth 0..10 m)
//!   ─ 4×4 stride-4 conv 4→32, ReLU          (patchify: H/4)
//!   ─ 3×3 stride-2 conv 32→64, ReLU         (H/8)
//!   ─ + (3×3 depthwise conv, ReLU, 1×1 conv 64→64)   (a residual step of context), ReLU
//! [B, 64, H/8, W/8]
//! ```
//! About 2.0 M multiply-adds for a 64×64 frame — the small CNN costs 2.2 M for RGB and 1.8 M more
//! for depth. The weights file holds this trunk only (what a policy freezes); the pretraining
//! heads stay with the pretraining.

use std::collections::BTreeMap;
use std::path::Path;

use safetensors::{Dtype, SafeTensors, tensor::TensorView};
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor, nn};

/// Input channels: R, G, B, depth.
pub const IN_CHANNELS: i64 = 4;
/// Channels of the feature map.
pub const FEATURE_CHANNELS: i64 = 64;
/// Input pixels per feature cell along each side.
pub const STRIDE: i64 = 8;
/// Tag in every weights file's metadata.
pub const FORMAT: &str = "gesthor-rgbd-encoder-1";
/// Tag of a pretrained ResNet-18 trunk's file (torchvision's names: `model.resnet_weights`).
pub const RESNET18_FORMAT: &str = "gesthor-resnet18-torchvision-1";
/// The one metadata key of a weights file (one key keeps the file's bytes deterministic: the
/// safetensors writer orders several keys by a hash map).
const META_KEY: &str = "gesthor_encoder";

/// The trunk. Variables: `patch.*`, `down.*`, `context_dw.*`, `context_pw.*` under its path.
#[derive(Debug)]
pub struct RgbdEncoder {
    patch: nn::Conv2D,
    down: nn::Conv2D,
    context_dw: nn::Conv2D,
    context_pw: nn::Conv2D,
}

impl RgbdEncoder {
    pub fn new(p: &nn::Path) -> RgbdEncoder {
        let c = FEATURE_CHANNELS;
        RgbdEncoder {
            patch: nn::conv2d(p / "patch", IN_CHANNELS, 32, 4, nn::ConvConfig { stride: 4, ..Default::default() }),
            down: nn::conv2d(p / "down", 32, c, 3, nn::ConvConfig { stride: 2, padding: 1, ..Default::default() }),
            context_dw: nn::conv2d(
                p / "context_dw",
                c,
                c,
                3,
                nn::ConvConfig { padding: 1, groups: c, ..Default::default() },
            ),
            context_pw: nn::conv2d(p / "context_pw", c, c, 1, Default::default()),
        }
    }

    /// `[B, 4, H, W]` in 0..1 → `[B, 64, H/8, W/8]` (H and W multiples of 8).
    pub fn forward(&self, x: &Tensor) -> Tensor {
        let y = x.apply(&self.patch).relu().apply(&self.down).relu();
        let context = y.apply(&self.context_dw).relu().apply(&self.context_pw);
        (y + context).relu()
    }
}

/// The encoder's input from frames in the form the wire and the rollout keep them: RGB u8
/// `[B, H, W, 3]` and depth as Int16 bit patterns `[B, H, W]` → f32 `[B, 4, H, W]` in 0..1
/// (the units of `inputs::rgb_unit` and `inputs::depth_unit`; converting before permuting reads
/// the bytes in order).
pub fn encoder_input(rgb: &Tensor, depth: &Tensor) -> Tensor {
    let rgb = rgb.to_kind(Kind::Float).permute([0, 3, 1, 2]) / 255.0;
    let depth = (depth.to_kind(Kind::Int).bitwise_and(0xFFFF).to_kind(Kind::Float) / 65535.0).unsqueeze(1);
    Tensor::cat(&[rgb, depth], 1)
}

/// What a weights file says about the encoder it holds (its one metadata entry).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EncoderInfo {
    pub format: String,
    /// Frame size it was trained on.
    pub width: u32,
    pub height: u32,
    pub in_channels: i64,
    pub feature_channels: i64,
    pub stride: i64,
}

impl EncoderInfo {
    pub fn new(width: u32, height: u32) -> EncoderInfo {
        EncoderInfo {
            format: FORMAT.into(),
            width,
            height,
            in_channels: IN_CHANNELS,
            feature_channels: FEATURE_CHANNELS,
            stride: STRIDE,
        }
    }

    /// A ResNet-18 trunk's: RGB or depth (grey) as a 3-channel image → conv5.
    pub fn resnet18(width: u32, height: u32) -> EncoderInfo {
        EncoderInfo {
            format: RESNET18_FORMAT.into(),
            width,
            height,
            in_channels: 3,
            feature_channels: crate::net::resnet::CONV5_CHANNELS,
            stride: crate::net::resnet::CONV5_STRIDE,
        }
    }
}

/// A weights file that cannot be used: which file, why.
#[derive(Debug, thiserror::Error)]
#[error("encoder weights {file}: {message}")]
pub struct EncoderFileError {
    pub file: String,
    pub message: String,
}

fn file_error(path: &Path, message: impl Into<String>) -> EncoderFileError {
    EncoderFileError { file: path.display().to_string(), message: message.into() }
}

/// The bytes of a weights file holding the variables of `vs` under `prefix.` (names stored
/// without it), in name order; the same variables always give the same bytes.
pub fn weights_bytes(vs: &nn::VarStore, prefix: &str, info: &EncoderInfo) -> Result<Vec<u8>, String> {
    let lead = format!("{prefix}.");
    let mut blobs: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    for (name, t) in vs.variables().into_iter().collect::<BTreeMap<_, _>>() {
        let Some(short) = name.strip_prefix(&lead) else { continue };
        let t = t.detach().to_device(Device::Cpu).to_kind(Kind::Float).contiguous();
        let mut data = vec![0u8; t.numel() * 4];
        t.copy_data_u8(&mut data, t.numel());
        blobs.push((short.to_string(), t.size().iter().map(|&d| d as usize).collect(), data));
    }
    if blobs.is_empty() {
        return Err(format!("no variables under `{prefix}`"));
    }
    let views = blobs
        .iter()
        .map(|(n, s, d)| TensorView::new(Dtype::F32, s.clone(), d).map(|v| (n.as_str(), v)))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| e.to_string())?;
    let meta = [(META_KEY.to_string(), serde_json::to_string(info).expect("serialises"))].into_iter().collect();
    safetensors::serialize(views, Some(meta)).map_err(|e| e.to_string())
}

/// Hex sha256 of bytes (what the pretraining report records of the weights file).
pub use farm::files::sha256_hex;

/// Reads a weights file: its metadata and tensors by (short) name.
pub fn read_weights(path: &Path) -> Result<(EncoderInfo, BTreeMap<String, Tensor>), EncoderFileError> {
    let bytes = std::fs::read(path).map_err(|e| {
        let hint = if e.kind() == std::io::ErrorKind::NotFound {
            " (make it with `orchestrator encoder pretrain`)"
        } else {
            ""
        };
        file_error(path, format!("cannot read: {e}{hint}"))
    })?;
    let st = SafeTensors::deserialize(&bytes)
        .map_err(|e| file_error(path, format!("not a complete safetensors file (truncated or corrupted?): {e}")))?;
    let (_, header) = SafeTensors::read_metadata(&bytes).map_err(|e| file_error(path, e.to_string()))?;
    let raw = header
        .metadata()
        .as_ref()
        .and_then(|m| m.get(META_KEY))
        .ok_or_else(|| file_error(path, "not an encoder weights file (no `gesthor_encoder` metadata)"))?;
    let info: EncoderInfo =
        serde_json::from_str(raw).map_err(|e| file_error(path, format!("metadata `{META_KEY}`: {e}")))?;
    if info.format == RESNET18_FORMAT {
        return Err(file_error(path, "a ResNet-18 trunk: give it as model.resnet_weights (configs/faithful)"));
    }
    if info.format != FORMAT {
        return Err(file_error(path, format!("format `{}`; this build reads `{FORMAT}`", info.format)));
    }
    let mut tensors = BTreeMap::new();
    for (name, v) in st.tensors() {
        if v.dtype() != Dtype::F32 {
            return Err(file_error(path, format!("tensor `{name}` is {:?}, expected F32", v.dtype())));
        }
        let shape: Vec<i64> = v.shape().iter().map(|&d| d as i64).collect();
        let t = Tensor::f_from_data_size(v.data(), &shape, Kind::Float)
            .map_err(|e| file_error(path, format!("tensor `{name}`: {e}")))?;
        tensors.insert(name, t);
    }
    Ok((info, tensors))
}

/// Loads a weights file into the variables of `vs` under `prefix.`: it must have been trained on
/// frames of `frame` (width, height), every variable there must be in the file with its shape,
/// and nothing else may be.
pub fn load_weights(
    path: &Path,
    vs: &nn::VarStore,
    prefix: &str,
    frame: (u32, u32),
) -> Result<EncoderInfo, EncoderFileError> {
    let (info, tensors) = read_weights(path)?;
    if (info.width, info.height) != frame {
        return Err(file_error(
            path,
            format!(
                "trained on {}×{} frames; this run's are {}×{} (env.width, env.height): pretrain one with \
                 `orchestrator encoder pretrain --size {}`",
                info.width, info.height, frame.0, frame.1, frame.0
            ),
        ));
    }
    if (info.in_channels, info.feature_channels, info.stride) != (IN_CHANNELS, FEATURE_CHANNELS, STRIDE) {
        return Err(file_error(
            path,
            format!(
                "an encoder of {} input channels, {} features, stride {}; this build's has {IN_CHANNELS}, \
                 {FEATURE_CHANNELS}, {STRIDE}",
                info.in_channels, info.feature_channels, info.stride
            ),
        ));
    }
    let lead = format!("{prefix}.");
    let vars: BTreeMap<String, Tensor> =
        vs.variables().into_iter().filter_map(|(n, t)| n.strip_prefix(&lead).map(|s| (s.to_string(), t))).collect();
    for (name, var) in &vars {
        let src = tensors.get(name).ok_or_else(|| file_error(path, format!("has no `{name}`")))?;
        if src.size() != var.size() {
            return Err(file_error(path, format!("`{name}` is {:?}, the encoder needs {:?}", src.size(), var.size())));
        }
    }
    if let Some(name) = tensors.keys().find(|n| !vars.contains_key(*n)) {
        return Err(file_error(path, format!("holds `{name}`, which this encoder does not have")));
    }
    tch::no_grad(|| {
        for (name, mut var) in vars {
            var.copy_(&tensors[&name].to_kind(var.kind()).to_device(var.device()));
        }
    });
    Ok(info)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn feature_map_is_an_eighth_of_the_frame() {
        let vs = nn::VarStore::new(Device::Cpu);
        let enc = RgbdEncoder::new(&(vs.root() / "enc"));
        let rgb = Tensor::zeros([2, 64, 64, 3], (Kind::Uint8, Device::Cpu));
        let depth = Tensor::zeros([2, 64, 64], (Kind::Int16, Device::Cpu));
        let x = encoder_input(&rgb, &depth);
        assert_eq!(x.size(), [2, 4, 64, 64]);
        assert_eq!(enc.forward(&x).size(), [2, FEATURE_CHANNELS, 8, 8]);
        let rgb = Tensor::randint(256, [2, 8, 8, 3], (Kind::Uint8, Device::Cpu));
        let depth = Tensor::randint(65536, [2, 8, 8], (Kind::Int, Device::Cpu)).to_kind(Kind::Int16);
        let same = Tensor::cat(&[crate::inputs::rgb_unit(&rgb), crate::inputs::depth_unit(&depth)], 1);
        assert!(encoder_input(&rgb, &depth).allclose(&same, 0.0, 0.0, false), "the policy's input units");
    }

    #[test]
    fn weights_round_trip_and_mismatches_name_the_file() {
        let vs = nn::VarStore::new(Device::Cpu);
        let enc = crate::device::seeded(1, || RgbdEncoder::new(&(vs.root() / "trunk")));
        let info = EncoderInfo::new(64, 64);
        let bytes = weights_bytes(&vs, "trunk", &info).unwrap();
        assert_eq!(bytes, weights_bytes(&vs, "trunk", &info).unwrap(), "same variables, same bytes");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("enc.safetensors");
        std::fs::write(&path, &bytes).unwrap();

        let other = nn::VarStore::new(Device::Cpu);
        let enc2 = crate::device::seeded(2, || RgbdEncoder::new(&(other.root() / "policy" / "encoder")));
        assert_eq!(load_weights(&path, &other, "policy.encoder", (64, 64)).unwrap(), info);
        let x = crate::device::seeded(3, || Tensor::rand([1, 4, 64, 64], (Kind::Float, Device::Cpu)));
        assert!(enc.forward(&x).allclose(&enc2.forward(&x), 0.0, 0.0, false));

        let e = load_weights(&path, &other, "policy.encoder", (128, 128)).unwrap_err().to_string();
        assert!(e.contains("enc.safetensors") && e.contains("64×64") && e.contains("128×128"), "{e}");
        let e = load_weights(&dir.path().join("none.safetensors"), &other, "policy.encoder", (64, 64))
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.safetensors") && e.contains("encoder pretrain"), "{e}");
        // another network's variables under the prefix: a shape that does not fit is named
        let small = nn::VarStore::new(Device::Cpu);
        let _ = nn::conv2d(small.root() / "enc" / "patch", 3, 32, 4, Default::default());
        let e = load_weights(&path, &small, "enc", (64, 64)).unwrap_err().to_string();
        assert!(e.contains("enc.safetensors") && e.contains("patch.weight"), "{e}");
        std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
        let e = load_weights(&path, &other, "policy.encoder", (64, 64)).unwrap_err().to_string();
        assert!(e.contains("enc.safetensors") && e.contains("truncated"), "{e}");
    }
}
