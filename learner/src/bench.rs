//! Throughput figures of the learner (used by `learner bench` and the criterion bench): a policy
//! forward for a batch of envs, the visual encoders alone, and one PPO update on a stored
//! rollout — the tiny small-CNN network beside the same network on the frozen pretrained
//! encoder. Timings are measured, never asserted.

use std::path::{Path, PathBuf};
use std::time::Instant;

use farm::config::{Encoder, GestureNetwork, Method, RunConfig};
use rand::Rng;
use shm_schema::action;
use tch::{Device, Tensor, nn};

use crate::LearnerError;
use crate::net::agent::{ActMode, Actions, Agent, AgentError};
use crate::obs::{EnvStep, GestureKind, ObsError, OwnedObs};
use crate::ppo::trainer::Trainer;

/// The tiny CPU network of `configs/tiny-e2e/both.toml`: 64×64, small CNN, hidden 256, 1-layer GRU.
pub fn tiny_config() -> RunConfig {
    RunConfig::from_toml(
        "[run]\nmethod = \"both\"\n[env]\nwidth = 64\nheight = 64\n\
         [model]\nencoder = \"small_cnn\"\nhidden = 256\ngru_layers = 1\n",
        "bench-tiny",
    )
    .expect("valid")
}

/// The tiny network on the frozen pretrained RGB-D encoder (`configs/tiny/both.toml`),
/// with the given weights file.
pub fn tiny_frozen_config(weights: &Path) -> RunConfig {
    let mut c = tiny_config();
    c.model.encoder = Encoder::Pretrained;
    c.model.encoder_weights = Some(weights.to_path_buf());
    c
}

/// `cfg` reading the gesture as configs/tiny does: the flat layer beside the per-frame network,
/// turned by the person's pose (`model.gesture_network = "flat_and_turned"`,
/// `model.person_pose = true`).
pub fn turned_config(mut cfg: RunConfig) -> RunConfig {
    cfg.model.gesture_network = GestureNetwork::FlatAndTurned;
    cfg.model.person_pose = true;
    cfg
}

/// The PPO settings of `configs/tiny-e2e/both.toml` (2 epochs × 2 minibatches over 128 steps).
pub fn with_tiny_ppo(mut c: RunConfig) -> RunConfig {
    c.ppo.rollout = 128;
    c.ppo.epochs = 2;
    c.ppo.minibatches = 2;
    c
}

/// Writes a randomly initialised pretrained-encoder file for `size`² frames (timing does not
/// depend on the values; `orchestrator encoder pretrain` makes real ones).
pub fn random_encoder_weights(dir: &Path, size: u32) -> Result<PathBuf, LearnerError> {
    let vs = nn::VarStore::new(Device::Cpu);
    // `seeded` keeps these draws out of the sequence of a network another thread builds meanwhile
    let _trunk = crate::device::seeded(0, || crate::encoder::RgbdEncoder::new(&(vs.root() / "trunk")));
    let bytes = crate::encoder::net::weights_bytes(&vs, "trunk", &crate::encoder::EncoderInfo::new(size, size))
        .map_err(AgentError::Config)?;
    let path = dir.join(format!("rgbd{size}-random.safetensors"));
    std::fs::write(&path, bytes).map_err(|e| AgentError::Config(format!("{}: {e}", path.display())))?;
    Ok(path)
}

/// The dissertation's network (224², frozen ResNet-18, hidden 512, 2-layer GRU), with the given
/// ResNet weights file.
pub fn faithful_config(weights: &Path) -> RunConfig {
    let mut c = RunConfig::from_toml("[run]\nmethod = \"both\"\n", "bench-faithful").expect("valid");
    c.model.resnet_weights = Some(weights.to_path_buf());
    c
}

/// Writes a randomly initialised torchvision-named ResNet-18 (timing does not depend on the
/// values; ImageNet weights are the user's to supply).
pub fn random_resnet_weights(dir: &Path) -> Result<PathBuf, LearnerError> {
    let vs = nn::VarStore::new(Device::Cpu);
    let _net = crate::device::seeded(0, || crate::net::resnet::Resnet18::new(&vs.root()));
    let path = dir.join("resnet18-random.safetensors");
    vs.save(&path).map_err(|e| AgentError::Config(format!("{}: {e}", path.display())))?;
    Ok(path)
}

/// A random observation batch for `n` envs.
pub fn random_obs(n: usize, side: usize, seed: u64) -> OwnedObs {
    let mut rng = farm::seed::rng(seed, &[]);
    let mut o = OwnedObs::new(n, side, side);
    o.rgb.iter_mut().for_each(|v| *v = rng.random());
    o.depth.iter_mut().for_each(|v| *v = rng.random());
    o.gesture.iter_mut().for_each(|v| *v = half::f16::from_f32(rng.random::<f32>() - 0.5));
    for (i, e) in o.envs.iter_mut().enumerate() {
        *e = EnvStep {
            episode_start: true,
            gesture: GestureKind::Referencing,
            target: (i as i64 * 5) % shm_schema::TARGET_CATEGORIES as i64,
            ..Default::default()
        };
    }
    o
}

/// One measured figure.
#[derive(Clone, Debug)]
pub struct Figure {
    pub name: String,
    /// Median milliseconds per repetition.
    pub ms: f64,
    pub reps: usize,
}

impl std::fmt::Display for Figure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:<58} {:>10.2} ms  (median of {})", self.name, self.ms, self.reps)
    }
}

fn median_ms(mut f: impl FnMut(), reps: usize) -> f64 {
    f(); // warm-up
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// [`median_ms`] of a step that can fail: the first error, if any, instead of a time.
fn median_ms_or_error<E: Into<LearnerError>>(
    mut f: impl FnMut() -> Result<(), E>,
    reps: usize,
) -> Result<f64, LearnerError> {
    let mut err = None;
    let ms = median_ms(
        || {
            if let Err(e) = f() {
                err.get_or_insert(e);
            }
        },
        reps,
    );
    err.map_or(Ok(ms), |e| Err(e.into()))
}

/// Envs per worker in the benches' batches: frames arrive as workers send them, one group each
/// (configs/faithful-gpu's 32 envs a worker).
const WORKER_ENVS: usize = 32;

/// Acting on one step of `batch` envs: frames in, actions out (the frozen trunk included).
pub fn forward(name: &str, cfg: &RunConfig, batch: usize, device: Device, reps: usize) -> Result<Figure, LearnerError> {
    let mut p = Agent::new(cfg, batch, device)?;
    let o = random_obs(batch, cfg.env.width as usize, 1);
    let ms = median_ms_or_error(|| p.act(&o.batch_grouped(WORKER_ENVS), ActMode::Sample).map(drop), reps)?;
    Ok(Figure { name: format!("{name}: act, batch {batch}"), ms, reps })
}

/// A training step of `batch` envs as the farm's rounds run it (`Trainer::step` short of an
/// update): acting, and storing the step in the rollout (its frozen features, gestures,
/// feedback).
pub fn train_step(
    name: &str,
    cfg: &RunConfig,
    batch: usize,
    device: Device,
    reps: usize,
) -> Result<Figure, LearnerError> {
    let mut t = Trainer::new(cfg, batch, device)?;
    // short of the rollout's end: the warm-up and every repetition store a step
    let reps = reps.min(t.rollout.steps - 1);
    let o = random_obs(batch, cfg.env.width as usize, 1);
    let ms = median_ms_or_error(|| t.step(&o.batch_grouped(WORKER_ENVS)).map(drop), reps)?;
    Ok(Figure { name: format!("{name}: act and store, batch {batch}"), ms, reps })
}

/// The visual encoders alone on one step of `batch` envs: frames in, visual features out (what
/// acting pays for vision: both small CNNs, or the pretrained encoder and its head).
pub fn visual_forward(
    name: &str,
    cfg: &RunConfig,
    batch: usize,
    device: Device,
    reps: usize,
) -> Result<Figure, LearnerError> {
    let mut vision = cfg.clone();
    vision.run.method = Method::VisionOnly;
    let p = Agent::new(&vision, batch, device)?;
    let o = random_obs(batch, cfg.env.width as usize, 1);
    let ms = median_ms_or_error(
        || {
            let (x, _) = p.prepare(0, &o.batch())?;
            let _ = tch::no_grad(|| p.net.encode(&x));
            Ok::<_, ObsError>(())
        },
        reps,
    )?;
    Ok(Figure { name: format!("{name}: batch {batch} ({:.3} ms a frame)", ms / batch as f64), ms, reps })
}

/// Fills a trainer's rollout with `rollout × envs` steps of stored inputs (the same frames and
/// gestures at every step: acting is not what is measured; the person's pose, where it is an
/// input, new at every step), episodes of about 30 steps.
pub fn fill_rollout(t: &mut Trainer, seed: u64) -> Result<(), LearnerError> {
    let n = t.rollout.envs;
    let side = t.cfg.env.width as usize;
    let o = random_obs(n, side, seed);
    let (still, _) = t.agent.prepare(0, &o.batch())?;
    let mut rng = farm::seed::rng(seed, &[1]);
    t.rollout.begin(t.agent.hidden());
    for _ in 0..t.rollout.steps {
        // the person's pose relative to the robot changes as the robot moves: with the pose an
        // input, no stored step shows the previous one's (the gestures stay, as in an episode)
        let mut moved = t.cfg.model.person_pose.then(|| random_obs(n, side, seed));
        if let Some(m) = &mut moved {
            m.envs.iter_mut().for_each(|e| e.person_pose = [rng.random(), rng.random(), rng.random()]);
        }
        let moved = moved.as_ref().map(|m| t.agent.prepare(0, &m.batch())).transpose()?;
        let x = moved.as_ref().map_or(&still, |(x, _)| x);
        let starts: Vec<bool> = (0..n).map(|_| rng.random::<f32>() < 1.0 / 30.0).collect();
        let acted = Actions {
            actions: (0..n).map(|_| rng.random_range(0..action::COUNT as i64)).collect(),
            log_probs: vec![(1.0 / action::COUNT as f32).ln(); n],
            values: (0..n).map(|_| rng.random::<f32>() - 0.5).collect(),
        };
        t.rollout.push(x, &starts, &acted, &vec![true; n]);
    }
    for (i, r) in t.rollout.rewards.iter_mut().enumerate() {
        *r = if i % 37 == 0 { 1.0 } else { -0.001 };
    }
    let steps = t.rollout.steps;
    for i in 0..(steps - 1) * n {
        t.rollout.ends[i] = t.rollout.starts[i + n];
    }
    Ok(())
}

/// One PPO update (4 epochs) on `rollout × envs` stored samples.
pub fn update(name: &str, cfg: &RunConfig, envs: usize, device: Device, reps: usize) -> Result<Figure, LearnerError> {
    let mut t = Trainer::new(cfg, envs, device)?;
    fill_rollout(&mut t, 3)?;
    let bootstrap = vec![0.0f32; envs];
    let ms = median_ms(
        || {
            t.update(&bootstrap);
            if device.is_cuda() {
                tch::Cuda::synchronize(0);
            }
        },
        reps,
    );
    let samples = t.rollout.steps * envs;
    Ok(Figure {
        name: format!("{name}: PPO update ({} epochs, {} minibatch), {samples} samples", t.hp.epochs, t.hp.minibatches),
        ms,
        reps,
    })
}

/// Size in MiB of a rollout's stored inputs (what stays on the device).
pub fn rollout_mib(t: &Trainer) -> f64 {
    let bytes = |v: &Tensor| v.numel() * v.kind().elt_size_in_bytes();
    let rows = t.rollout.inputs().map(|x| x.fields().iter().filter_map(|(_, v)| *v).map(bytes).sum::<usize>());
    let gestures = t.rollout.gestures().map(|g| bytes(&g.rows()) + bytes(g.ids()));
    (rows.unwrap_or(0) + gestures.unwrap_or(0)) as f64 / (1024.0 * 1024.0)
}

/// One PPO update on whatever the trainer's rollout holds (for benches).
pub fn update_once(t: &mut Trainer) -> crate::logs::metrics::UpdateMetrics {
    let bootstrap = vec![0.0f32; t.rollout.envs];
    t.update(&bootstrap)
}

/// `learner bench`: the tiny network's figures, and with `faithful` the dissertation's at its
/// sizes (its ResNet-18 weights random, written to a temporary directory), each handed to `out`
/// as measured.
pub fn run(
    device: Device,
    faithful: Option<FaithfulSizes>,
    reps: usize,
    mut out: impl FnMut(&Figure),
) -> anyhow::Result<()> {
    let tiny = tiny_config();
    out(&forward("tiny (64², small CNN, 256, GRU 1)", &tiny, 32, device, reps)?);
    out(&update("tiny (64², small CNN, 256, GRU 1)", &tiny, 10, device, reps)?);
    // the small CNNs beside the frozen pretrained encoder, 4,096 frames an update (128 × 32)
    let dir = tempfile::tempdir()?;
    let frozen = tiny_frozen_config(&random_encoder_weights(dir.path(), 64)?);
    out(&visual_forward("visual: small CNN for RGB + small CNN for depth", &tiny, 32, device, reps)?);
    out(&visual_forward("visual: pretrained RGB-D encoder + head", &frozen, 32, device, reps)?);
    out(&forward("tiny-frozen (pretrained RGB-D encoder, 256, GRU 1)", &frozen, 32, device, reps)?);
    out(&update("tiny, tiny PPO", &with_tiny_ppo(tiny.clone()), 32, device, reps)?);
    out(&update("tiny-frozen, tiny PPO", &with_tiny_ppo(frozen.clone()), 32, device, reps)?);
    // the gesture read flat and per frame, turned by the person's pose (the pose new at every
    // stored step, as in training)
    let turned = turned_config(frozen);
    out(&forward("tiny-frozen, gesture flat and turned + pose", &turned, 32, device, reps)?);
    out(&update("tiny-frozen, gesture flat and turned + pose, tiny PPO", &with_tiny_ppo(turned), 32, device, reps)?);
    if let Some(sizes) = faithful {
        let dir = tempfile::tempdir()?;
        let weights = random_resnet_weights(dir.path())?;
        let cfg = faithful_config(&weights);
        let reps_slow = if device.is_cuda() { reps } else { reps.clamp(1, 3) };
        for &n in &sizes.act {
            if device.is_cuda() {
                for f in transfer(&cfg, n, device, reps_slow) {
                    out(&f);
                }
            }
            out(&forward("faithful (224², frozen ResNet-18, 512, GRU 2)", &cfg, n, device, reps_slow)?);
            out(&train_step("faithful (224², frozen ResNet-18, 512, GRU 2)", &cfg, n, device, reps_slow)?);
        }
        if device.is_cuda()
            && let Some(&n) = sizes.act.iter().max()
        {
            for f in trunk(n, device, reps_slow) {
                out(&f);
            }
            println!(
                "frozen ResNet-18 in bf16, folded and fused, against f32 with its norms: {:.4} of the scale",
                trunk_error(8, device)
            );
        }
        for &(envs, minibatches) in &sizes.update {
            let mut c = cfg.clone();
            c.ppo.minibatches = minibatches;
            out(&update("faithful, stored conv5 features (GRU + heads + 1x1 convs)", &c, envs, device, reps_slow)?);
        }
    }
    Ok(())
}

/// The faithful network's batch sizes for `learner bench`: acting rounds of `act` envs, and PPO
/// updates of `(envs, minibatches)` (each env 128 steps).
#[derive(Clone, Debug, PartialEq)]
pub struct FaithfulSizes {
    pub act: Vec<usize>,
    pub update: Vec<(usize, usize)>,
}

/// The frozen ResNet-18 alone on one acting round's images (RGB and depth of `batch` envs at
/// 224²), in bf16 and channels-last as acting runs it: with its batch norms, and folded (on a
/// GPU its convolutions fused with their ReLU and residual sum) — what `FrozenTrunk` runs now.
pub fn trunk(batch: usize, device: Device, reps: usize) -> Vec<Figure> {
    use crate::net::layers::channels_last;
    use crate::net::resnet::Resnet18;
    let x = channels_last(&Tensor::rand([2 * batch as i64, 3, 224, 224], (tch::Kind::BFloat16, device)));
    [("with batch norms", false), ("folded, fused on a GPU", true)]
        .into_iter()
        .map(|(way, folded)| {
            let mut vs = nn::VarStore::new(device);
            let net = if folded { Resnet18::folded(&vs.root()) } else { Resnet18::new(&vs.root()) };
            crate::net::layers::bf16_channels_last(&mut vs);
            let ms = median_ms(
                || {
                    let _ = tch::no_grad(|| net.forward(&x));
                    if device.is_cuda() {
                        tch::Cuda::synchronize(0);
                    }
                },
                reps,
            );
            Figure { name: format!("frozen ResNet-18, {} images of 224², bf16, {way}", 2 * batch), ms, reps }
        })
        .collect()
}

/// How far acting's bf16 trunk (folded; fused on a GPU) is from the f32 trunk with its batch
/// norms, every norm's statistics drawn at random, on `batch` random 224² images: the largest
/// difference over the largest value — a check that the fold and the fused kernels compute what
/// they replace, on the device the bench runs on.
pub fn trunk_error(batch: usize, device: Device) -> f64 {
    let vs = nn::VarStore::new(device);
    let f = crate::device::seeded(11, || crate::net::layers::FrozenTrunk::new(&vs, true));
    crate::device::seeded(12, || f.vary_batch_norms(&vs));
    let x = crate::device::seeded(13, || Tensor::rand([batch as i64, 3, 224, 224], (tch::Kind::Float, device)));
    f.bf16_error(&x).expect("a bf16 copy was asked for")
}

/// The frames of one round of `batch` envs onto a GPU (224² RGB u8 and 16-bit depth, in groups
/// of 32 envs as workers send them): straight from pageable memory, as the workers' shared
/// memory is, and through the pinned staging buffer acting uses (`crate::inputs::Staging`).
pub fn transfer(cfg: &RunConfig, batch: usize, device: Device, reps: usize) -> Vec<Figure> {
    let o = random_obs(batch, cfg.env.width as usize, 1);
    let mb = (o.rgb.len() + 2 * o.depth.len()) as f64 / 1e6;
    let staging = crate::inputs::Staging::default();
    let ways: [(&str, &dyn Fn() -> (Tensor, Tensor)); 2] = [
        ("pageable", &|| {
            let b = o.batch_grouped(WORKER_ENVS);
            (crate::inputs::rgb_tensor(&b, device), crate::inputs::depth_tensor(&b, device))
        }),
        ("pinned staging", &|| {
            let b = o.batch_grouped(WORKER_ENVS);
            (staging.rgb(&b, device), staging.depth(&b, device))
        }),
    ];
    ways.iter()
        .map(|(way, copy)| {
            let ms = median_ms(
                || {
                    let _ = copy();
                    tch::Cuda::synchronize(0);
                },
                reps,
            );
            Figure { name: format!("frames to the GPU, batch {batch}, {mb:.0} MB, {way}"), ms, reps }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The training-step figure runs on the CPU and stops short of an update (the repetitions
    /// are held under the rollout's length).
    #[test]
    fn train_step_figure_runs_on_the_cpu_short_of_an_update() {
        let mut cfg = tiny_config();
        cfg.ppo.rollout = 3;
        let f = train_step("tiny", &cfg, 2, Device::Cpu, 9).unwrap();
        assert!(f.ms > 0.0 && f.reps == 2, "{f}");
    }

    /// The trunk figures the GPU bench prints, made on the CPU: two, each a time.
    #[test]
    fn trunk_figures_run_on_the_cpu() {
        let figures = trunk(1, Device::Cpu, 1);
        assert_eq!(figures.len(), 2);
        assert!(figures.iter().all(|f| f.ms > 0.0 && f.name.contains("2 images of 224²")), "{figures:?}");
        let e = trunk_error(1, Device::Cpu);
        assert!(e < 0.05, "bf16 trunk {e} of the scale from the f32 one");
    }
}
