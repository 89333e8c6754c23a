//! Pretraining the RGB-D encoder on a frame set (`learner pretrain-encoder`): per feature cell,
//! the class the id target shows there (37 targets, the person, other; cross-entropy) and the
//! mean depth (L1). RGB or depth is zeroed in some frames so a policy may drop either (T4.7).
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

use super::net::{EncoderInfo, FEATURE_CHANNELS, RgbdEncoder, STRIDE, encoder_input, sha256_hex, weights_bytes};

/// Keys of the pretraining's random streams.
const KEY_INIT: u64 = 0xE4C0_0100;
const KEY_EPOCH: u64 = 0xE4C0_0101;

/// How to pretrain.
#[derive(Clone, Debug)]
pub struct PretrainOptions {
    /// The frame set (`orchestrator encoder pretrain` writes `STEM.frames`).
    pub frames: PathBuf,
    /// Output stem: `STEM.safetensors` and `STEM.json`.
    pub out: PathBuf,
    pub seed: u64,
    pub epochs: usize,
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
            batch: 64,
            lr: 2e-3,
            other_weight: 0.3,
            depth_weight: 2.0,
            drop_rgb: 0.15,
            drop_depth: 0.15,
            threads: 2,
        }
    }
}

/// Held-out figures: per-cell accuracy over all cells, over cells showing a target or the
/// person, and over the person's cells (None when there are no such cells); mean depth error.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HeldOut {
    pub accuracy: Option<f64>,
    pub accuracy_targets_and_person: Option<f64>,
    pub accuracy_person: Option<f64>,
    pub depth_error_m: f64,
}

impl std::fmt::Display for HeldOut {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
        write!(
            f,
            "accuracy {} (targets and person {}, person {}), depth error {:.3} m",
            a(self.accuracy),
            a(self.accuracy_targets_and_person),
            a(self.accuracy_person),
            self.depth_error_m
        )
    }
}

/// The JSON written beside the weights (`STEM.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PretrainReport {
    /// Training seed, and the seed the frames were drawn from.
    pub seed: u64,
    pub frames_seed: u64,
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

/// Errors of pretraining; each names its file.
#[derive(Debug, thiserror::Error)]
pub enum PretrainError {
    #[error(transparent)]
    Frames(#[from] farm::frame_set::FrameSetError),
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

impl Data {
    fn new(set: &FrameSet) -> Data {
        let h = &set.header;
        let (n, hh, ww, g) = (set.len() as i64, h.height as i64, h.width as i64, h.grid as i64);
        let as_i16 = |v: &[u16]| v.iter().map(|&x| x as i16).collect::<Vec<i16>>();
        let (held, train): (Vec<i64>, Vec<i64>) = (0..n).partition(|&i| set.is_held_out(i as usize));
        Data {
            rgb: Tensor::from_slice(&set.rgb).view([n, hh, ww, 3]),
            depth: Tensor::from_slice(&as_i16(&set.depth)).view([n, hh, ww]),
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

/// The trunk and the pretraining heads.
struct Model {
    trunk: RgbdEncoder,
    class_head: nn::Conv2D,
    depth_head: nn::Conv2D,
    grid: i64,
}

impl Model {
    /// Class logits `[B, C, g, g]` and depth `[B, g, g]` (0..1) of encoder inputs.
    fn forward(&self, x: &Tensor) -> (Tensor, Tensor) {
        let mut f = self.trunk.forward(x);
        if f.size()[2] != self.grid || f.size()[3] != self.grid {
            f = f.adaptive_avg_pool2d([self.grid, self.grid]);
        }
        (f.apply(&self.class_head), f.apply(&self.depth_head).squeeze_dim(1))
    }
}

/// Zeroes RGB or depth per frame: `keep_rgb`/`keep_depth` are 0/1 per frame.
fn drop_channels(x: &Tensor, keep_rgb: &Tensor, keep_depth: &Tensor) -> Tensor {
    let b = x.size()[0];
    let mask = Tensor::cat(&[keep_rgb.view([b, 1]).expand([b, 3], false), keep_depth.view([b, 1])], 1);
    x * mask.view([b, 4, 1, 1])
}

/// Figures over frames `idx` with the given channel mask (1, 1 = both).
fn evaluate(model: &Model, d: &Data, idx: &[i64], keep: (f64, f64), dev: Device) -> HeldOut {
    if idx.is_empty() {
        return HeldOut::default();
    }
    let (mut correct, mut cells, mut fg_correct, mut fg, mut p_correct, mut p, mut depth_err) =
        (0i64, 0i64, 0i64, 0i64, 0i64, 0i64, 0f64);
    tch::no_grad(|| {
        for chunk in idx.chunks(256) {
            let i = Tensor::from_slice(chunk);
            let b = chunk.len() as i64;
            let x = encoder_input(&d.rgb.index_select(0, &i), &d.depth.index_select(0, &i)).to_device(dev);
            let ones = Tensor::ones([b], (Kind::Float, dev));
            let x = drop_channels(&x, &(&ones * keep.0), &(&ones * keep.1));
            let (logits, depth) = model.forward(&x);
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
    let h = set.header.clone();
    let file = o.frames.display().to_string();
    let unusable = |message: String| PretrainError::Unusable { file: file.clone(), message };
    if h.classes != CLASSES {
        return Err(unusable(format!("{} classes, the encoder's labels have {CLASSES}", h.classes)));
    }
    if h.width as i64 % STRIDE != 0 || h.height as i64 % STRIDE != 0 || h.width as i64 / STRIDE < h.grid as i64 {
        return Err(unusable(format!(
            "frames of {}×{} with {} cells: the size must be a multiple of {STRIDE} and give at least one feature per cell",
            h.width, h.height, h.grid
        )));
    }
    let data = Data::new(&set);
    if data.train.is_empty() {
        return Err(unusable("no frames outside the held-out rooms to train on".into()));
    }
    tch::set_num_threads(o.threads);
    let vs = nn::VarStore::new(dev);
    let root = vs.root();
    let model = crate::device::seeded(farm::seed::mix(o.seed, &[KEY_INIT]) as i64, || Model {
        trunk: RgbdEncoder::new(&(&root / "trunk")),
        class_head: nn::conv2d(&root / "class_head", FEATURE_CHANNELS, CLASSES as i64, 1, Default::default()),
        depth_head: nn::conv2d(&root / "depth_head", FEATURE_CHANNELS, 1, 1, Default::default()),
        grid: h.grid as i64,
    });
    let mut opt = nn::Adam::default().build(&vs, o.lr).expect("adam");
    let mut class_weights = vec![1f32; CLASSES as usize];
    class_weights[CLASS_OTHER as usize] = o.other_weight as f32;
    let class_weights = Tensor::from_slice(&class_weights).to_device(dev);
    let steps_per_epoch = data.train.len().div_ceil(o.batch);
    let total_steps = (steps_per_epoch * o.epochs).max(1);
    let started = Instant::now();
    let mut step = 0usize;
    let mut held = HeldOut::default();
    for epoch in 0..o.epochs {
        let mut rng = farm::seed::rng(o.seed, &[KEY_EPOCH, epoch as u64]);
        let mut order = data.train.clone();
        order.shuffle(&mut rng);
        let mut loss_sum = 0.0;
        for chunk in order.chunks(o.batch) {
            opt.set_lr(o.lr * (1.0 - 0.9 * step as f64 / total_steps as f64));
            let b = chunk.len();
            let (mut keep_rgb, mut keep_depth, mut flip) = (vec![1f32; b], vec![1f32; b], vec![false; b]);
            for k in 0..b {
                let u: f64 = rng.random();
                if u < o.drop_rgb {
                    keep_rgb[k] = 0.0;
                } else if u < o.drop_rgb + o.drop_depth {
                    keep_depth[k] = 0.0;
                }
                flip[k] = rng.random_bool(0.5);
            }
            let i = Tensor::from_slice(chunk);
            let x = encoder_input(&data.rgb.index_select(0, &i), &data.depth.index_select(0, &i)).to_device(dev);
            let x = drop_channels(
                &x,
                &Tensor::from_slice(&keep_rgb).to_device(dev),
                &Tensor::from_slice(&keep_depth).to_device(dev),
            );
            let mut class = data.class.index_select(0, &i).to_device(dev);
            let mut cell_depth = data.cell_depth.index_select(0, &i).to_device(dev);
            // Mirror the chosen frames left–right, labels with them.
            let f = Tensor::from_slice(&flip).to_device(dev);
            let x = x.flip([3]).where_self(&f.view([b as i64, 1, 1, 1]), &x);
            class = class.flip([2]).where_self(&f.view([b as i64, 1, 1]), &class);
            cell_depth = cell_depth.flip([2]).where_self(&f.view([b as i64, 1, 1]), &cell_depth);
            let (logits, depth) = model.forward(&x);
            let ce = logits.cross_entropy_loss(&class, Some(&class_weights), Reduction::Mean, -100, 0.0);
            let l1 = (depth - cell_depth).abs().mean(Kind::Float);
            let loss = ce + l1 * o.depth_weight;
            opt.backward_step(&loss);
            loss_sum += loss.double_value(&[]) * b as f64;
            step += 1;
        }
        held = evaluate(&model, &data, &data.held, (1.0, 1.0), dev);
        let spent = started.elapsed().as_secs_f64();
        println!(
            "epoch {:>2}/{}: loss {:.4}; held-out {held}; {spent:.0} s, about {:.0} s left",
            epoch + 1,
            o.epochs,
            loss_sum / data.train.len() as f64,
            spent / (epoch + 1) as f64 * (o.epochs - epoch - 1) as f64
        );
    }
    let training_seconds = started.elapsed().as_secs_f64();
    let rgb_only = evaluate(&model, &data, &data.held, (1.0, 0.0), dev);
    let depth_only = evaluate(&model, &data, &data.held, (0.0, 1.0), dev);

    let weights_path = with_ext(&o.out, "safetensors");
    let bytes = weights_bytes(&vs, "trunk", &EncoderInfo::new(h.width, h.height))
        .map_err(|m| PretrainError::Unusable { file: weights_path.display().to_string(), message: m })?;
    let write_error = |p: &Path, e: std::io::Error| PretrainError::Unusable {
        file: p.display().to_string(),
        message: format!("cannot write: {e}"),
    };
    farm::files::write_atomic(&weights_path, &bytes).map_err(|e| write_error(&weights_path, e))?;
    let report = PretrainReport {
        seed: o.seed,
        frames_seed: h.seed,
        frame_set: file.clone(),
        width: h.width,
        height: h.height,
        grid: h.grid,
        classes: h.classes,
        in_channels: super::net::IN_CHANNELS,
        feature_channels: FEATURE_CHANNELS,
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
        "encoder: {} ({} training frames, {} held-out, {} with the person) in {:.0} s\n  held-out: {held}\n  \
         RGB only: {rgb_only}\n  depth only: {depth_only}\n  sha256 {}",
        weights_path.display(),
        report.training_frames,
        report.held_out_frames,
        persons,
        training_seconds,
        report.sha256
    );
    Ok(report)
}
