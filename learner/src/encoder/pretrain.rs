//! Pretraining the RGB-D encoder on a frame set (`learner pretrain-encoder`), by one of two
//! objectives ([`Objective`]):
//!
//! - **contrast** (label-free, the default): two views of each frame, each with its own colour
//!   and depth jitter and a quarter of its cells hidden; each cell's features (through a small
//!   projection) must pick out the same cell of the other view among the cells of the batch
//!   (InfoNCE, as dense contrastive learning does): features that tell places apart, whatever the
//!   lighting. No label of any kind is read: the role ImageNet plays for the dissertation.
//! - **reconstruct** (label-free): one linear map per cell (64 features → the cell's 8×8 RGB-D
//!   pixels) must give the whole frame back (`mask`: a share of cells hidden from the trunk).
//!   Its features read the category and the person no better than the raw pixels do (the probes,
//!   docs/experiments), the contrast's read the person better.
//! - **semantic** (the "semantic sensor", an ablation beyond the dissertation): per feature cell,
//!   the class the id target shows there (37 targets, the person, other; cross-entropy) and the
//!   mean depth (L1) — a segmentation of the task's own answer.
//!
//! RGB or depth is zeroed in some frames so a policy may drop either (T4.7); with the
//! reconstruction objective the missing modality is then predicted from the other.
//!
//! The trunk ([`Trunk`]) is the early-fusion RGB-D encoder of `configs/tiny`, or §4.3.3's
//! ResNet-18 (contrast only): RGB and depth as two images through the one trunk, as
//! `configs/faithful`'s frozen trunk reads them, written with torchvision's names — the faithful
//! config's label-free trunk where no ImageNet checkpoint is supplied.
//!
//! Reproducible: the weights' sha256 depends only on the frame set, the seed and the options.
//! Initial weights come from `tch::manual_seed`; shuffling, channel drops and flips from
//! `farm::seed` streams; torch runs on a fixed number of CPU threads.

use std::path::{Path, PathBuf};
use std::time::Instant;

use farm::files::with_ext;
use farm::frame_set::{CLASS_OTHER, CLASSES, FLAG_PERSON, FrameSet};
use farm::rooms::SceneId;
use rand::Rng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Reduction, Tensor, nn, nn::OptimizerConfig};

use super::net::{
    EncoderInfo, FEATURE_CHANNELS, IN_CHANNELS, RgbdEncoder, STRIDE, encoder_input, sha256_hex, weights_bytes,
};
use crate::net::layers::resnet_input;
use crate::net::resnet::Resnet18;

/// Keys of the pretraining's random streams.
const KEY_INIT: u64 = 0xE4C0_0100;
const KEY_EPOCH: u64 = 0xE4C0_0101;
/// The default weight of the "other" cell class (the probes weigh it the same).
pub(super) const OTHER_WEIGHT: f64 = 0.3;

/// What the trunk is trained to give.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Objective {
    /// RGB-D reconstruction through the feature map: no labels.
    Reconstruct,
    /// Dense contrast of two jittered views: no labels.
    #[default]
    Contrast,
    /// Per-cell target category, person and depth from the id target: the semantic sensor.
    Semantic,
}

/// Contrast: the temperature of the cells' similarities, the width of the projection, the share
/// of cells hidden in each view, and the jitter (RGB gain per channel ±, RGB offset ±, depth gain ±).
const TEMPERATURE: f64 = 0.2;
const PROJECTION: i64 = 32;
const CONTRAST_HIDE: f64 = 0.25;
const JITTER: (f64, f64, f64) = (0.3, 0.1, 0.1);
/// Contrast: cells a training step contrasts against all cells of the batch (all would make a
/// 4,096² similarity matrix a step: too slow on two cores).
const ANCHORS: usize = 512;

/// The network pretrained.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Trunk {
    /// The early-fusion RGB-D encoder (`super::net`): `configs/tiny`'s.
    #[default]
    Rgbd,
    /// ResNet-18 up to conv5 (`crate::net::resnet`), RGB and depth (grey) as two images through
    /// it: `configs/faithful`'s trunk.
    Resnet18,
}

impl Trunk {
    /// What its weights file says of it (channels in and out, pixels per cell) for frames of
    /// `width`×`height`.
    fn info(self, width: u32, height: u32) -> EncoderInfo {
        match self {
            Trunk::Rgbd => EncoderInfo::new(width, height),
            Trunk::Resnet18 => EncoderInfo::resnet18(width, height),
        }
    }

    /// Images the trunk sees per frame: one RGB-D image, or RGB and depth apart.
    fn images_per_frame(self) -> usize {
        match self {
            Trunk::Rgbd => 1,
            Trunk::Resnet18 => 2,
        }
    }
}

impl std::str::FromStr for Trunk {
    type Err = String;
    fn from_str(s: &str) -> Result<Trunk, String> {
        match s {
            "rgbd" => Ok(Trunk::Rgbd),
            "resnet18" => Ok(Trunk::Resnet18),
            _ => Err(format!("`{s}`: the trunks are `rgbd` (configs/tiny) and `resnet18` (configs/faithful)")),
        }
    }
}

impl std::fmt::Display for Trunk {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Trunk::Rgbd => "rgbd",
            Trunk::Resnet18 => "resnet18",
        })
    }
}

impl std::str::FromStr for Objective {
    type Err = String;
    fn from_str(s: &str) -> Result<Objective, String> {
        match s {
            "reconstruct" => Ok(Objective::Reconstruct),
            "contrast" => Ok(Objective::Contrast),
            "semantic" => Ok(Objective::Semantic),
            _ => Err(format!("`{s}`: the objectives are `reconstruct`, `contrast` (label-free) and `semantic`")),
        }
    }
}

impl std::fmt::Display for Objective {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Objective::Reconstruct => "reconstruct",
            Objective::Contrast => "contrast",
            Objective::Semantic => "semantic",
        })
    }
}

/// How to pretrain.
#[derive(Clone, Debug)]
pub struct PretrainOptions {
    /// The frame set (`orchestrator encoder pretrain` writes `STEM.frames`).
    pub frames: PathBuf,
    /// Output stem: `STEM.safetensors` and `STEM.json`.
    pub out: PathBuf,
    pub seed: u64,
    pub epochs: usize,
    pub objective: Objective,
    pub trunk: Trunk,
    /// Reconstruction: the share of 8×8-pixel cells hidden from the trunk in each training frame.
    pub mask: f64,
    pub batch: usize,
    /// Adam's learning rate at the start; it falls linearly to a tenth by the end.
    pub lr: f64,
    /// Weight of the "other" class in the cross-entropy (the others weigh 1): most cells show
    /// walls, floor and furniture, and an unweighted loss first learns to say "other" everywhere.
    pub other_weight: f64,
    /// Weight of the depth L1 loss (depth in 0..1 = 0..10 m) beside the class cross-entropy.
    pub depth_weight: f64,
    /// Share of training frames with RGB zeroed, and (separately) with depth zeroed.
    pub drop_rgb: f64,
    pub drop_depth: f64,
    /// Torch CPU threads; fixed so that the result does not depend on the machine's cores.
    pub threads: i32,
}

impl PretrainOptions {
    pub fn new(frames: PathBuf, out: PathBuf, seed: u64, epochs: usize) -> PretrainOptions {
        PretrainOptions {
            frames,
            out,
            seed,
            epochs,
            objective: Objective::default(),
            trunk: Trunk::default(),
            mask: 0.0,
            batch: 64,
            lr: 2e-3,
            other_weight: OTHER_WEIGHT,
            depth_weight: 2.0,
            drop_rgb: 0.15,
            drop_depth: 0.15,
            threads: 2,
        }
    }
}

/// Held-out figures of the objective itself. Semantic: per-cell accuracy over all cells, over
/// cells showing a target or the person, and over the person's cells (None when there are no such
/// cells), and the cells' mean depth error. Reconstruction (nothing hidden): the mean absolute
/// error of the frame given back, RGB in levels (0..255) and depth in metres. What the features
/// hold for the task is measured by `probe-encoder`, the same way for every objective.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HeldOut {
    pub accuracy: Option<f64>,
    pub accuracy_targets_and_person: Option<f64>,
    pub accuracy_person: Option<f64>,
    pub depth_error_m: f64,
    #[serde(default)]
    pub rgb_error: Option<f64>,
    /// Contrast: the share of cells whose nearest cell of a jittered view is their own.
    #[serde(default)]
    pub cells_matched: Option<f64>,
}

impl std::fmt::Display for HeldOut {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
        match (self.rgb_error, self.cells_matched) {
            (Some(rgb), _) => write!(f, "RGB error {rgb:.1} levels, depth error {:.3} m", self.depth_error_m),
            (_, Some(m)) => write!(f, "cells matched across views {m:.3}"),
            _ => write!(
                f,
                "accuracy {} (targets and person {}, person {}), depth error {:.3} m",
                a(self.accuracy),
                a(self.accuracy_targets_and_person),
                a(self.accuracy_person),
                self.depth_error_m
            ),
        }
    }
}

/// The JSON written beside the weights (`STEM.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PretrainReport {
    /// Training seed, and the seed the frames were drawn from.
    pub seed: u64,
    pub frames_seed: u64,
    /// What the trunk was trained to give (`semantic` read the id target's labels).
    #[serde(default = "semantic")]
    pub objective: Objective,
    #[serde(default)]
    pub trunk: Trunk,
    /// Reconstruction's hidden share of cells.
    #[serde(default)]
    pub mask: f64,
    pub frame_set: String,
    pub width: u32,
    pub height: u32,
    pub grid: u32,
    pub classes: u32,
    pub in_channels: i64,
    pub feature_channels: i64,
    /// Rooms trained on and rooms held out for the figures below.
    pub rooms: Vec<String>,
    pub held_out_rooms: Vec<String>,
    pub frames: usize,
    pub training_frames: usize,
    pub held_out_frames: usize,
    pub epochs: usize,
    pub batch: usize,
    pub lr: f64,
    pub threads: i32,
    pub held_out: HeldOut,
    /// The same, with the depth channel zeroed (RGB only) and with RGB zeroed (depth only).
    pub held_out_rgb_only: HeldOut,
    pub held_out_depth_only: HeldOut,
    pub training_seconds: f64,
    pub weights: String,
    pub sha256: String,
}

/// Reports written before the objective was recorded came from the semantic objective.
fn semantic() -> Objective {
    Objective::Semantic
}

/// Errors of pretraining; each names its file.
#[derive(Debug, thiserror::Error)]
pub enum PretrainError {
    #[error(transparent)]
    Frames(#[from] farm::frame_set::FrameSetError),
    #[error("{0}")]
    Options(String),
    #[error("{file}: {message}")]
    Unusable { file: String, message: String },
}

/// The frame set as tensors, and which frames train and which are held out.
struct Data {
    rgb: Tensor,
    depth: Tensor,
    class: Tensor,
    cell_depth: Tensor,
    train: Vec<i64>,
    held: Vec<i64>,
}

/// A frame set's pixels in the wire's form: RGB u8 `[N, H, W, 3]`, depth as Int16 bit patterns
/// `[N, H, W]` (what `encoder_input` takes).
pub(super) fn frame_tensors(set: &FrameSet) -> (Tensor, Tensor) {
    let (n, hh, ww) = (set.len() as i64, set.header.height as i64, set.header.width as i64);
    let depth: Vec<i16> = set.depth.iter().map(|&x| x as i16).collect();
    (Tensor::from_slice(&set.rgb).view([n, hh, ww, 3]), Tensor::from_slice(&depth).view([n, hh, ww]))
}

impl Data {
    fn new(set: &FrameSet) -> Data {
        let (n, g) = (set.len() as i64, set.header.grid as i64);
        let as_i16 = |v: &[u16]| v.iter().map(|&x| x as i16).collect::<Vec<i16>>();
        let (held, train): (Vec<i64>, Vec<i64>) = (0..n).partition(|&i| set.is_held_out(i as usize));
        let (rgb, depth) = frame_tensors(set);
        Data {
            rgb,
            depth,
            class: Tensor::from_slice(&set.cell_class).view([n, g, g]).to_kind(Kind::Int64),
            cell_depth: Tensor::from_slice(&as_i16(&set.cell_depth))
                .view([n, g, g])
                .to_kind(Kind::Int)
                .bitwise_and(0xFFFF)
                .to_kind(Kind::Float)
                / 65535.0,
            train,
            held,
        }
    }
}

/// The trunk and the pretraining heads of its objective.
struct Model {
    trunk: TrunkNet,
    head: Head,
}

enum TrunkNet {
    Rgbd(RgbdEncoder),
    Resnet18(Resnet18),
}

enum Head {
    Semantic {
        class: nn::Conv2D,
        depth: nn::Conv2D,
        grid: i64,
    },
    /// One 1×1 conv: each feature cell's 64 values → its STRIDE×STRIDE×4 pixels.
    Reconstruct {
        pixels: nn::Conv2D,
    },
    /// 1×1 conv, ReLU, 1×1 conv: each cell's features → the space its similarities are taken in.
    Contrast {
        hidden: nn::Conv2D,
        out: nn::Conv2D,
    },
}

impl Model {
    /// `features`: the trunk's feature channels.
    fn new(root: &nn::Path, objective: Objective, trunk: Trunk, features: i64, grid: i64) -> Model {
        let trunk = match trunk {
            Trunk::Rgbd => TrunkNet::Rgbd(RgbdEncoder::new(&(root / "trunk"))),
            Trunk::Resnet18 => TrunkNet::Resnet18(Resnet18::new(&(root / "trunk"))),
        };
        let head = match objective {
            Objective::Semantic => Head::Semantic {
                class: nn::conv2d(root / "class_head", FEATURE_CHANNELS, CLASSES as i64, 1, Default::default()),
                depth: nn::conv2d(root / "depth_head", FEATURE_CHANNELS, 1, 1, Default::default()),
                grid,
            },
            Objective::Reconstruct => Head::Reconstruct {
                pixels: nn::conv2d(
                    root / "pixel_head",
                    FEATURE_CHANNELS,
                    IN_CHANNELS * STRIDE * STRIDE,
                    1,
                    Default::default(),
                ),
            },
            Objective::Contrast => Head::Contrast {
                hidden: nn::conv2d(root / "projection_hidden", features, features, 1, Default::default()),
                out: nn::conv2d(root / "projection_out", features, PROJECTION, 1, Default::default()),
            },
        };
        Model { trunk, head }
    }

    /// The feature maps of encoder inputs `[B, 4, H, W]`: one a frame (RGB-D), or for the
    /// ResNet one a frame and modality in `keep` (RGB, depth), the RGB images first, each
    /// ImageNet-normalised and depth as a grey image, as the policy's frozen trunk reads them.
    fn features(&self, x: &Tensor, keep: (bool, bool)) -> Tensor {
        match &self.trunk {
            TrunkNet::Rgbd(t) => t.forward(x),
            TrunkNet::Resnet18(t) => {
                let mut images = Vec::new();
                if keep.0 {
                    images.push(resnet_input(&x.narrow(1, 0, 3)));
                }
                if keep.1 {
                    images.push(resnet_input(&x.narrow(1, 3, 1)));
                }
                t.forward(&Tensor::cat(&images, 0))
            }
        }
    }

    /// Contrast: unit-length projections of every cell, `[images·g·g, PROJECTION]` (`keep`: the
    /// ResNet's modalities; the RGB-D trunk's inputs come with their channels zeroed instead).
    fn project(&self, x: &Tensor, keep: (bool, bool)) -> Tensor {
        let Head::Contrast { hidden, out } = &self.head else { unreachable!("a contrast head") };
        let z = self.features(x, keep).apply(hidden).relu().apply(out).permute([0, 2, 3, 1]).reshape([-1, PROJECTION]);
        let norm = z.square().sum_dim_intlist(1, true, Kind::Float).sqrt() + 1e-6;
        z / norm
    }

    /// Semantic: class logits `[B, C, g, g]` and depth `[B, g, g]` (0..1) of encoder inputs.
    fn semantic(&self, x: &Tensor) -> (Tensor, Tensor) {
        let Head::Semantic { class, depth, grid } = &self.head else { unreachable!("a semantic head") };
        let mut f = self.features(x, (true, true));
        if f.size()[2] != *grid || f.size()[3] != *grid {
            f = f.adaptive_avg_pool2d([*grid, *grid]);
        }
        (f.apply(class), f.apply(depth).squeeze_dim(1))
    }

    /// Reconstruction: the frame `[B, 4, H, W]` given back from encoder inputs.
    fn reconstruct(&self, x: &Tensor) -> Tensor {
        let Head::Reconstruct { pixels } = &self.head else { unreachable!("a reconstruction head") };
        self.features(x, (true, true)).apply(pixels).pixel_shuffle(STRIDE)
    }
}

/// Contrast: the InfoNCE loss of two views' cell projections (row k of each: the same cell), both
/// ways, for the cells `anchors` against every cell of the other view, and the share of anchors
/// whose most similar cell of the other view is their own.
fn info_nce(z1: &Tensor, z2: &Tensor, anchors: &Tensor) -> (Tensor, Tensor) {
    let one_way = |a: &Tensor, b: &Tensor| {
        let logits = a.index_select(0, anchors).matmul(&b.tr()) / TEMPERATURE;
        let matched = logits.argmax(1, false).eq_tensor(anchors).to_kind(Kind::Float).mean(Kind::Float);
        (logits.cross_entropy_for_logits(anchors), matched)
    };
    let ((l1, m1), (l2, m2)) = (one_way(z1, z2), one_way(z2, z1));
    ((l1 + l2) / 2.0, (m1 + m2) / 2.0)
}

/// Contrast: a view of frames `x` `[B, 4, H, W]`: per frame RGB gains and offset and a depth gain
/// (`jitter`: 5 values a frame), values kept in 0..1.
fn jittered(x: &Tensor, jitter: &[f32]) -> Tensor {
    let b = x.size()[0];
    let j = Tensor::from_slice(jitter).view([b, 5]).to_device(x.device());
    let gain = Tensor::cat(&[j.narrow(1, 0, 3), j.narrow(1, 4, 1)], 1).view([b, 4, 1, 1]);
    let offset = Tensor::cat(&[j.narrow(1, 3, 1).expand([b, 3], false), j.zeros_like().narrow(1, 0, 1)], 1);
    (x * gain + offset.view([b, 4, 1, 1])).clamp(0.0, 1.0)
}

/// Hides cells of the frames: `hide` is `[B, H/stride, W/stride]` of 0/1 (1: hidden).
fn hide_cells(x: &Tensor, hide: &Tensor, stride: i64) -> Tensor {
    let keep: Tensor = 1.0 - hide.unsqueeze(1);
    let keep = keep.repeat_interleave_self_int(stride, 2, None::<i64>);
    x * keep.repeat_interleave_self_int(stride, 3, None::<i64>)
}

/// Zeroes RGB or depth per frame: `keep_rgb`/`keep_depth` are 0/1 per frame.
fn drop_channels(x: &Tensor, keep_rgb: &Tensor, keep_depth: &Tensor) -> Tensor {
    let b = x.size()[0];
    let mask = Tensor::cat(&[keep_rgb.view([b, 1]).expand([b, 3], false), keep_depth.view([b, 1])], 1);
    x * mask.view([b, 4, 1, 1])
}

/// Frames `chunk` (indices into `d`) and their encoder inputs on `dev`.
fn held_batch(d: &Data, chunk: &[i64], dev: Device) -> (Tensor, Tensor) {
    let i = Tensor::from_slice(chunk);
    let x = encoder_input(&d.rgb.index_select(0, &i), &d.depth.index_select(0, &i)).to_device(dev);
    (i, x)
}

/// Inputs with RGB and depth scaled by `keep` (1, 1 = both; 1, 0 = RGB only).
fn keep_channels(x: &Tensor, keep: (f64, f64)) -> Tensor {
    let ones = Tensor::ones([x.size()[0]], (Kind::Float, x.device()));
    drop_channels(x, &(&ones * keep.0), &(&ones * keep.1))
}

/// Figures over frames `idx` with the given channel mask (1, 1 = both).
fn evaluate(model: &Model, d: &Data, idx: &[i64], keep: (f64, f64), dev: Device) -> HeldOut {
    if idx.is_empty() {
        return HeldOut::default();
    }
    match model.head {
        Head::Reconstruct { .. } => return evaluate_reconstruction(model, d, idx, keep, dev),
        Head::Contrast { .. } => return evaluate_contrast(model, d, idx, keep, dev),
        Head::Semantic { .. } => {}
    }
    let (mut correct, mut cells, mut fg_correct, mut fg, mut p_correct, mut p, mut depth_err) =
        (0i64, 0i64, 0i64, 0i64, 0i64, 0i64, 0f64);
    tch::no_grad(|| {
        for chunk in idx.chunks(256) {
            let (i, x) = held_batch(d, chunk, dev);
            let (logits, depth) = model.semantic(&keep_channels(&x, keep));
            let want = d.class.index_select(0, &i).to_device(dev);
            let hit = logits.argmax(1, false).eq_tensor(&want);
            let is_fg = want.ne(i64::from(CLASS_OTHER));
            let is_person = want.eq(i64::from(farm::frame_set::CLASS_PERSON));
            correct += hit.sum(Kind::Int64).int64_value(&[]);
            cells += want.numel() as i64;
            fg_correct += hit.logical_and(&is_fg).sum(Kind::Int64).int64_value(&[]);
            fg += is_fg.sum(Kind::Int64).int64_value(&[]);
            p_correct += hit.logical_and(&is_person).sum(Kind::Int64).int64_value(&[]);
            p += is_person.sum(Kind::Int64).int64_value(&[]);
            let err = (depth - d.cell_depth.index_select(0, &i).to_device(dev)).abs().sum(Kind::Double);
            depth_err += err.double_value(&[]);
        }
    });
    let ratio = |a: i64, b: i64| (b > 0).then(|| a as f64 / b as f64);
    HeldOut {
        accuracy: ratio(correct, cells),
        accuracy_targets_and_person: ratio(fg_correct, fg),
        accuracy_person: ratio(p_correct, p),
        depth_error_m: 10.0 * depth_err / cells as f64,
        rgb_error: None,
        cells_matched: None,
    }
}

/// Contrast's figure: cells matched between each frame and a fixed jitter of it (RGB × 0.85 +
/// 0.05, depth × 1.05), among the cells of 64 frames at a time.
fn evaluate_contrast(model: &Model, d: &Data, idx: &[i64], keep: (f64, f64), dev: Device) -> HeldOut {
    let (mut matched, mut chunks) = (0f64, 0f64);
    tch::no_grad(|| {
        for chunk in idx.chunks(64) {
            let (_, x) = held_batch(d, chunk, dev);
            let b = chunk.len() as i64;
            let fixed: Vec<f32> = (0..b).flat_map(|_| [0.85, 0.85, 0.85, 0.05, 1.05]).collect();
            let modalities = (keep.0 > 0.0, keep.1 > 0.0);
            let z1 = model.project(&keep_channels(&x, keep), modalities);
            let z2 = model.project(&keep_channels(&jittered(&x, &fixed), keep), modalities);
            let (_, m) = info_nce(&z1, &z2, &Tensor::arange(z1.size()[0], (Kind::Int64, dev)));
            matched += m.double_value(&[]) * b as f64;
            chunks += b as f64;
        }
    });
    HeldOut { cells_matched: Some(matched / chunks), ..HeldOut::default() }
}

/// Reconstruction's figures: the whole frame given back from the (channel-masked) input.
fn evaluate_reconstruction(model: &Model, d: &Data, idx: &[i64], keep: (f64, f64), dev: Device) -> HeldOut {
    let (mut rgb_err, mut depth_err, mut px) = (0f64, 0f64, 0f64);
    tch::no_grad(|| {
        for chunk in idx.chunks(256) {
            let (_, x) = held_batch(d, chunk, dev);
            let err = (model.reconstruct(&keep_channels(&x, keep)) - &x).abs();
            rgb_err += err.narrow(1, 0, 3).sum(Kind::Double).double_value(&[]);
            depth_err += err.narrow(1, 3, 1).sum(Kind::Double).double_value(&[]);
            px += (x.numel() / 4) as f64;
        }
    });
    HeldOut {
        accuracy: None,
        accuracy_targets_and_person: None,
        accuracy_person: None,
        depth_error_m: 10.0 * depth_err / px,
        rgb_error: Some(255.0 * rgb_err / (3.0 * px)),
        cells_matched: None,
    }
}

fn room_names(floorplans: impl Iterator<Item = u16>) -> Vec<String> {
    let mut v: Vec<u16> = floorplans.collect();
    v.sort_unstable();
    v.dedup();
    v.into_iter().map(|f| SceneId::parse(&f.to_string()).map_or_else(|| format!("#{f}"), |s| s.name())).collect()
}

/// Trains the encoder, writes `STEM.safetensors` (the trunk) and `STEM.json`, prints one line
/// per epoch with the held-out figures.
pub fn pretrain(o: &PretrainOptions, dev: Device) -> Result<PretrainReport, PretrainError> {
    let set = FrameSet::read(&o.frames)?;
    let info = check(o, &set)?;
    let data = Data::new(&set);
    if data.train.is_empty() {
        return Err(unusable(o, "no frames outside the held-out rooms to train on".into()));
    }
    tch::set_num_threads(o.threads);
    let vs = nn::VarStore::new(dev);
    let root = vs.root();
    let h = &set.header;
    let model = crate::device::seeded(farm::seed::mix(o.seed, &[KEY_INIT]) as i64, || {
        Model::new(&root, o.objective, o.trunk, info.feature_channels, h.grid as i64)
    });
    let started = Instant::now();
    let held = train(o, &model, &vs, &data, &info, (h.height, h.width), dev);
    let training_seconds = started.elapsed().as_secs_f64();
    let rgb_only = evaluate(&model, &data, &data.held, (1.0, 0.0), dev);
    let depth_only = evaluate(&model, &data, &data.held, (0.0, 1.0), dev);
    write(o, &set, &data, &vs, &info, [held, rgb_only, depth_only], training_seconds)
}

fn unusable(o: &PretrainOptions, message: String) -> PretrainError {
    PretrainError::Unusable { file: o.frames.display().to_string(), message }
}

/// The trunk's shapes for the frame set, or why the set or the options cannot be pretrained on.
fn check(o: &PretrainOptions, set: &FrameSet) -> Result<EncoderInfo, PretrainError> {
    let h = &set.header;
    if o.objective == Objective::Semantic && h.classes != CLASSES {
        return Err(unusable(o, format!("{} classes, the encoder's labels have {CLASSES}", h.classes)));
    }
    if o.trunk == Trunk::Resnet18 && o.objective != Objective::Contrast {
        return Err(PretrainError::Options(format!(
            "the ResNet-18 trunk is pretrained by the contrast objective only, not `{}`",
            o.objective
        )));
    }
    let info = o.trunk.info(h.width, h.height);
    let stride = info.stride;
    if h.width as i64 % stride != 0 || h.height as i64 % stride != 0 || h.width as i64 / STRIDE < h.grid as i64 {
        return Err(unusable(
            o,
            format!(
                "frames of {}×{} with {} cells: for the {} trunk the size must be a multiple of {stride} and give \
                 at least one feature per cell",
                h.width, h.height, h.grid, o.trunk
            ),
        ));
    }
    Ok(info)
}

/// The epochs: each shuffles the training frames, takes Adam steps on batches of them at a
/// linearly decaying rate, and reports the held-out figures. Returns the last of those.
fn train(
    o: &PretrainOptions,
    model: &Model,
    vs: &nn::VarStore,
    data: &Data,
    info: &EncoderInfo,
    (height, width): (u32, u32),
    dev: Device,
) -> HeldOut {
    let cells = (height as i64 / info.stride, width as i64 / info.stride);
    let mut opt = nn::Adam::default().build(vs, o.lr).expect("adam");
    let mut class_weights = vec![1f32; CLASSES as usize];
    class_weights[CLASS_OTHER as usize] = o.other_weight as f32;
    let class_weights = Tensor::from_slice(&class_weights).to_device(dev);
    let total_steps = (data.train.len().div_ceil(o.batch) * o.epochs).max(1);
    let started = Instant::now();
    let mut step = 0usize;
    let mut held = None;
    for epoch in 0..o.epochs {
        let mut rng = farm::seed::rng(o.seed, &[KEY_EPOCH, epoch as u64]);
        let mut order = data.train.clone();
        order.shuffle(&mut rng);
        let mut loss_sum = 0.0;
        for chunk in order.chunks(o.batch) {
            opt.set_lr(o.lr * (1.0 - 0.9 * step as f64 / total_steps as f64));
            let draws = Draws::new(o, &mut rng, chunk.len(), cells);
            let loss = batch_loss(o, model, data, chunk, &draws, &class_weights, info.stride, dev);
            opt.backward_step(&loss);
            loss_sum += loss.double_value(&[]) * chunk.len() as f64;
            step += 1;
        }
        let h = evaluate(model, data, &data.held, (1.0, 1.0), dev);
        let spent = started.elapsed().as_secs_f64();
        println!(
            "epoch {:>2}/{}: loss {:.4}; held-out {h}; {spent:.0} s, about {:.0} s left",
            epoch + 1,
            o.epochs,
            loss_sum / data.train.len() as f64,
            spent / (epoch + 1) as f64 * (o.epochs - epoch - 1) as f64
        );
        held = Some(h);
    }
    held.unwrap_or_else(|| evaluate(model, data, &data.held, (1.0, 1.0), dev))
}

/// One batch's random draws, in the order the seed's stream gives them: per frame a channel
/// drop and a flip; the hidden cells (reconstruction); per contrast view each frame's jitter and
/// hidden cells, then the anchor cells.
struct Draws {
    keep_rgb: Vec<f32>,
    keep_depth: Vec<f32>,
    flip: Vec<bool>,
    hidden: Vec<f32>,
    /// Feature cells of a frame (rows, columns): the hidden cells' shape.
    cells: (i64, i64),
    /// Contrast: per view, each frame's jitter and hidden cells.
    views: Vec<(Vec<f32>, Vec<f32>)>,
    anchors: Vec<i64>,
}

impl Draws {
    fn new(o: &PretrainOptions, rng: &mut impl Rng, b: usize, cells: (i64, i64)) -> Draws {
        // The ResNet sees RGB and depth as images of their own: none is dropped.
        let (drop_rgb, drop_depth) = match o.trunk {
            Trunk::Rgbd => (o.drop_rgb, o.drop_depth),
            Trunk::Resnet18 => (0.0, 0.0),
        };
        let (mut keep_rgb, mut keep_depth, mut flip) = (vec![1f32; b], vec![1f32; b], vec![false; b]);
        let mut hidden = vec![0f32; b * (cells.0 * cells.1) as usize];
        for k in 0..b {
            let u: f64 = rng.random();
            if u < drop_rgb {
                keep_rgb[k] = 0.0;
            } else if u < drop_rgb + drop_depth {
                keep_depth[k] = 0.0;
            }
            flip[k] = rng.random_bool(0.5);
        }
        if o.objective == Objective::Reconstruct && o.mask > 0.0 {
            hidden.iter_mut().for_each(|c| *c = if rng.random_bool(o.mask) { 1.0 } else { 0.0 });
        }
        let (mut views, mut anchors) = (Vec::new(), Vec::new());
        if o.objective == Objective::Contrast {
            let (g, off, dg) = JITTER;
            for _ in 0..2 {
                let mut j = Vec::with_capacity(b * 5);
                for _ in 0..b {
                    j.extend((0..3).map(|_| rng.random_range(1.0 - g..1.0 + g) as f32));
                    j.push(rng.random_range(-off..off) as f32);
                    j.push(rng.random_range(1.0 - dg..1.0 + dg) as f32);
                }
                let hide = (0..hidden.len()).map(|_| if rng.random_bool(CONTRAST_HIDE) { 1.0 } else { 0.0 }).collect();
                views.push((j, hide));
            }
            let rows = hidden.len() * o.trunk.images_per_frame();
            anchors = rand::seq::index::sample(rng, rows, ANCHORS.min(rows)).into_iter().map(|k| k as i64).collect();
        }
        Draws { keep_rgb, keep_depth, flip, hidden, cells, views, anchors }
    }
}

/// The objective's loss on the frames `chunk`, augmented by `d`.
#[allow(clippy::too_many_arguments)]
fn batch_loss(
    o: &PretrainOptions,
    model: &Model,
    data: &Data,
    chunk: &[i64],
    d: &Draws,
    class_weights: &Tensor,
    stride: i64,
    dev: Device,
) -> Tensor {
    let b = chunk.len() as i64;
    let i = Tensor::from_slice(chunk);
    let whole = encoder_input(&data.rgb.index_select(0, &i), &data.depth.index_select(0, &i)).to_device(dev);
    // Mirror the chosen frames left–right (labels with them below).
    let f = Tensor::from_slice(&d.flip).to_device(dev);
    let whole = whole.flip([3]).where_self(&f.view([b, 1, 1, 1]), &whole);
    let keep = (Tensor::from_slice(&d.keep_rgb).to_device(dev), Tensor::from_slice(&d.keep_depth).to_device(dev));
    let x = drop_channels(&whole, &keep.0, &keep.1);
    let hidden = |hide: &[f32]| Tensor::from_slice(hide).view([b, d.cells.0, d.cells.1]).to_device(dev);
    match o.objective {
        Objective::Reconstruct => {
            (model.reconstruct(&hide_cells(&x, &hidden(&d.hidden), stride)) - &whole).abs().mean(Kind::Float)
        }
        Objective::Contrast => {
            let z: Vec<Tensor> = d
                .views
                .iter()
                .map(|(jitter, hide)| {
                    let v = drop_channels(&jittered(&whole, jitter), &keep.0, &keep.1);
                    model.project(&hide_cells(&v, &hidden(hide), stride), (true, true))
                })
                .collect();
            info_nce(&z[0], &z[1], &Tensor::from_slice(&d.anchors).to_device(dev)).0
        }
        Objective::Semantic => {
            let mut class = data.class.index_select(0, &i).to_device(dev);
            let mut cell_depth = data.cell_depth.index_select(0, &i).to_device(dev);
            class = class.flip([2]).where_self(&f.view([b, 1, 1]), &class);
            cell_depth = cell_depth.flip([2]).where_self(&f.view([b, 1, 1]), &cell_depth);
            let (logits, depth) = model.semantic(&x);
            let ce = logits.cross_entropy_loss(&class, Some(class_weights), Reduction::Mean, -100, 0.0);
            ce + (depth - cell_depth).abs().mean(Kind::Float) * o.depth_weight
        }
    }
}

/// Writes the weights and the report beside them; `held`: all inputs, RGB only, depth only.
fn write(
    o: &PretrainOptions,
    set: &FrameSet,
    data: &Data,
    vs: &nn::VarStore,
    info: &EncoderInfo,
    [held, rgb_only, depth_only]: [HeldOut; 3],
    training_seconds: f64,
) -> Result<PretrainReport, PretrainError> {
    let h = &set.header;
    let weights_path = with_ext(&o.out, "safetensors");
    let bytes = weights_bytes(vs, "trunk", info)
        .map_err(|m| PretrainError::Unusable { file: weights_path.display().to_string(), message: m })?;
    let write_error = |p: &Path, e: std::io::Error| PretrainError::Unusable {
        file: p.display().to_string(),
        message: format!("cannot write: {e}"),
    };
    farm::files::write_atomic(&weights_path, &bytes).map_err(|e| write_error(&weights_path, e))?;
    let report = PretrainReport {
        seed: o.seed,
        frames_seed: h.seed,
        objective: o.objective,
        trunk: o.trunk,
        mask: match o.objective {
            Objective::Reconstruct => o.mask,
            Objective::Contrast => CONTRAST_HIDE,
            Objective::Semantic => 0.0,
        },
        frame_set: o.frames.display().to_string(),
        width: h.width,
        height: h.height,
        grid: h.grid,
        classes: h.classes,
        in_channels: info.in_channels,
        feature_channels: info.feature_channels,
        rooms: room_names(data.train.iter().map(|&i| set.rooms[i as usize])),
        held_out_rooms: room_names(h.held_out.iter().copied()),
        frames: set.len(),
        training_frames: data.train.len(),
        held_out_frames: data.held.len(),
        epochs: o.epochs,
        batch: o.batch,
        lr: o.lr,
        threads: o.threads,
        held_out: held,
        held_out_rgb_only: rgb_only,
        held_out_depth_only: depth_only,
        training_seconds,
        weights: weights_path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
        sha256: sha256_hex(&bytes),
    };
    let json_path = with_ext(&o.out, "json");
    let json = serde_json::to_string_pretty(&report).expect("serialises") + "\n";
    farm::files::write_atomic(&json_path, json.as_bytes()).map_err(|e| write_error(&json_path, e))?;
    let persons = set.flags.iter().filter(|&&f| f & FLAG_PERSON != 0).count();
    println!(
        "encoder: {} ({} training frames, {} held-out, {} with the person) in {:.0} s\n  held-out: {}\n  \
         RGB only: {}\n  depth only: {}\n  sha256 {}",
        weights_path.display(),
        report.training_frames,
        report.held_out_frames,
        persons,
        training_seconds,
        report.held_out,
        report.held_out_rgb_only,
        report.held_out_depth_only,
        report.sha256
    );
    Ok(report)
}
