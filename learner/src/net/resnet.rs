//! ResNet-18 up to conv5 (`layer4`), with torchvision's parameter names, and the loader for a
//! torchvision checkpoint the user supplies (ImageNet weights cannot be downloaded here).
//!
//! Batch norm always runs on its running statistics (eval mode): with ImageNet weights that is
//! what a frozen backbone means; without weights the network is trained from scratch and batch
//! norm acts as a learned per-channel affine — acting and learning then see the same function,
//! which PPO's probability ratio needs. For that case the last batch norm of each residual block
//! starts at zero (torchvision's `zero_init_residual`), so the untrained trunk starts near the
//! identity instead of blowing activations up.

use std::collections::HashMap;
use std::path::Path;

use tch::{Device, Kind, Tensor, nn};

const IMAGENET_MEAN: [f64; 3] = [0.485, 0.456, 0.406];
const IMAGENET_STD: [f64; 3] = [0.229, 0.224, 0.225];

/// Channels of conv5.
pub const CONV5_CHANNELS: i64 = 512;
/// Input pixels per conv5 cell along each side (a stride of 2 five times).
pub const CONV5_STRIDE: i64 = 32;

/// Spatial size of conv5 for an input side of `n` pixels (224 → 7).
pub fn conv5_side(n: i64) -> i64 {
    let conv = |n: i64, k: i64, s: i64, p: i64| (n + 2 * p - k) / s + 1;
    let mut n = conv(n, 7, 2, 3); // conv1
    n = conv(n, 3, 2, 1); // max pool
    for _ in 0..3 {
        n = conv(n, 3, 2, 1); // first block of layer2..4
    }
    n
}

/// Normalises images in 0..1 (`[B, 3, H, W]`) with ImageNet's statistics.
pub fn imagenet_normalize(x: &Tensor) -> Tensor {
    let opts = (Kind::Float, x.device());
    let mean = Tensor::from_slice(&IMAGENET_MEAN).to_kind(Kind::Float).view([1, 3, 1, 1]).to_device(opts.1);
    let std = Tensor::from_slice(&IMAGENET_STD).to_kind(Kind::Float).view([1, 3, 1, 1]).to_device(opts.1);
    (x - mean) / std
}

/// A convolution and its batch norm — or, in a folded trunk, the convolution alone with the
/// norm's frozen affine map folded into its weights and a bias ([`fold_batch_norms`]).
#[derive(Debug)]
struct ConvBn {
    conv: nn::Conv2D,
    bn: Option<nn::BatchNorm>,
    /// The convolution's stride and padding (tch keeps its config private), for the fused calls.
    stride: i64,
    padding: i64,
}

/// Set once cuDNN has refused a fused convolution here: the trunk then runs unfused.
static FUSED_REFUSED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// `fused()`, or `plain()` where the fused call is not to be tried or was refused (said once).
fn fused_or(fused: impl FnOnce() -> Result<Tensor, tch::TchError>, plain: impl FnOnce() -> Tensor) -> Tensor {
    use std::sync::atomic::Ordering;
    if !FUSED_REFUSED.load(Ordering::Relaxed) {
        match fused() {
            Ok(y) => return y,
            Err(e) => {
                if !FUSED_REFUSED.swap(true, Ordering::Relaxed) {
                    tracing::warn!("fused cuDNN convolutions refused, the trunk runs unfused: {e}");
                }
            }
        }
    }
    plain()
}

impl ConvBn {
    #[allow(clippy::too_many_arguments)]
    fn new(
        p: &nn::Path,
        conv: &str,
        bn: &str,
        c_in: i64,
        c_out: i64,
        k: i64,
        stride: i64,
        bn_zero: bool,
        folded: bool,
    ) -> ConvBn {
        let cfg = nn::ConvConfig { stride, padding: k / 2, bias: folded, ..Default::default() };
        let bn_cfg = nn::BatchNormConfig {
            ws_init: nn::Init::Const(if bn_zero { 0.0 } else { 1.0 }),
            bs_init: nn::Init::Const(0.0),
            ..Default::default()
        };
        ConvBn {
            conv: nn::conv2d(p / conv, c_in, c_out, k, cfg),
            bn: (!folded).then(|| nn::batch_norm2d(p / bn, c_out, bn_cfg)),
            stride,
            padding: k / 2,
        }
    }

    fn forward(&self, x: &Tensor) -> Tensor {
        let y = x.apply(&self.conv);
        match &self.bn {
            Some(bn) => y.apply_t(bn, false),
            None => y,
        }
    }

    /// Whether this convolution may run as one cuDNN kernel with what follows it: folded (no
    /// norm between) and on a GPU.
    fn fusable(&self, x: &Tensor) -> bool {
        self.bn.is_none() && x.device().is_cuda()
    }

    /// ReLU(conv(x)), in one kernel where it is fusable.
    fn forward_relu(&self, x: &Tensor) -> Tensor {
        let (s, p) = ([self.stride; 2], [self.padding; 2]);
        if !self.fusable(x) {
            return self.forward(x).relu();
        }
        fused_or(
            || x.f_cudnn_convolution_relu(&self.conv.ws, self.conv.bs.as_ref(), s, p, [1, 1], 1),
            || self.forward(x).relu(),
        )
    }

    /// ReLU(conv(x) + z), in one kernel where it is fusable.
    fn forward_add_relu(&self, x: &Tensor, z: &Tensor) -> Tensor {
        let (s, p) = ([self.stride; 2], [self.padding; 2]);
        if !self.fusable(x) {
            return (self.forward(x) + z).relu();
        }
        fused_or(
            || x.f_cudnn_convolution_add_relu(&self.conv.ws, z, 1.0, self.conv.bs.as_ref(), s, p, [1, 1], 1),
            || (self.forward(x) + z).relu(),
        )
    }
}

#[derive(Debug)]
struct BasicBlock {
    a: ConvBn,
    b: ConvBn,
    down: Option<ConvBn>,
}

impl BasicBlock {
    fn forward(&self, x: &Tensor) -> Tensor {
        let shortcut = match &self.down {
            Some(d) => d.forward(x),
            None => x.shallow_clone(),
        };
        self.b.forward_add_relu(&self.a.forward_relu(x), &shortcut)
    }
}

/// ResNet-18 without its pooling and classifier: image `[B, 3, H, W]` → conv5 `[B, 512, h, w]`.
#[derive(Debug)]
pub struct Resnet18 {
    stem: ConvBn,
    blocks: Vec<BasicBlock>,
}

impl Resnet18 {
    /// Builds the trunk under `p` with torchvision's names (`conv1`, `bn1`, `layer1.0.conv1`, ...).
    pub fn new(p: &nn::Path) -> Resnet18 {
        Resnet18::build(p, false)
    }

    /// The trunk without batch norms: each convolution has a bias instead, for weights made by
    /// [`fold_batch_norms`] (a frozen trunk only: no batch-norm kernels, each of which was a pass
    /// of its own over the activations). On a GPU its convolutions run fused with the ReLU (and
    /// the residual sum) that follow them, cuDNN's `convolution_relu` and `convolution_add_relu`.
    pub fn folded(p: &nn::Path) -> Resnet18 {
        Resnet18::build(p, true)
    }

    fn build(p: &nn::Path, folded: bool) -> Resnet18 {
        let conv_bn = |q: &nn::Path, conv, bn, c_in, c_out, k, stride, bn_zero| {
            ConvBn::new(q, conv, bn, c_in, c_out, k, stride, bn_zero, folded)
        };
        let stem = conv_bn(p, "conv1", "bn1", 3, 64, 7, 2, false);
        let mut blocks = Vec::new();
        let mut c_in = 64;
        for (layer, c_out) in [(1, 64), (2, 128), (3, 256), (4, 512)] {
            for i in 0..2 {
                let q = p / format!("layer{layer}") / i.to_string();
                let stride = if layer > 1 && i == 0 { 2 } else { 1 };
                let down = (stride != 1 || c_in != c_out)
                    .then(|| conv_bn(&(&q / "downsample"), "0", "1", c_in, c_out, 1, stride, false));
                blocks.push(BasicBlock {
                    a: conv_bn(&q, "conv1", "bn1", c_in, c_out, 3, stride, false),
                    b: conv_bn(&q, "conv2", "bn2", c_out, c_out, 3, 1, true),
                    down,
                });
                c_in = c_out;
            }
        }
        Resnet18 { stem, blocks }
    }

    pub fn forward(&self, x: &Tensor) -> Tensor {
        let mut x = self.stem.forward_relu(x).max_pool2d([3, 3], [2, 2], [1, 1], [1, 1], false);
        for b in &self.blocks {
            x = b.forward(&x);
        }
        x
    }
}

/// The weights of a folded trunk ([`Resnet18::folded`]) from a trunk's with batch norms, both
/// named as torchvision does under `prefix`: for each convolution `c` with norm `n` (eval mode,
/// ε = 1e-5), s = γ / √(σ² + ε), weight' = weight · s per output channel, bias' = β − μ · s.
/// `conv_var` is a variable of the folded trunk (`…conv1.weight`, `…downsample.0.bias`); the
/// result is in f32.
pub fn fold_batch_norms(vars: &HashMap<String, Tensor>, conv_var: &str) -> Tensor {
    let (conv, field) = conv_var.rsplit_once('.').expect("a variable name has a field");
    let bn = match conv.rsplit_once('.') {
        Some((block, "conv1")) => format!("{block}.bn1"),
        Some((block, "conv2")) => format!("{block}.bn2"),
        Some((down, "0")) => format!("{down}.1"),
        _ => conv.replace("conv1", "bn1"), // the stem at the root, `conv1`
    };
    let get = |name: String| vars.get(&name).unwrap_or_else(|| panic!("no {name} to fold")).to_kind(Kind::Float);
    let scale = get(format!("{bn}.weight")) / (get(format!("{bn}.running_var")) + 1e-5).sqrt();
    match field {
        "weight" => get(format!("{conv}.weight")) * scale.view([-1, 1, 1, 1]),
        "bias" => get(format!("{bn}.bias")) - get(format!("{bn}.running_mean")) * scale,
        other => panic!("{conv_var}: a folded convolution has no `{other}`"),
    }
}

#[derive(Debug, thiserror::Error)]
#[error("ResNet-18 weights {file}: {reason}")]
pub struct WeightsError {
    pub file: String,
    pub reason: String,
}

/// Reads the named tensors of a torchvision ResNet-18 checkpoint: `.safetensors`, or a
/// `.pt`/`.pth`/`.bin` state dict written by `torch.save` (see [`crate::net::pth`]).
pub fn read_torchvision(path: &Path) -> Result<HashMap<String, Tensor>, WeightsError> {
    let err = |reason: String| WeightsError { file: path.display().to_string(), reason };
    if !path.is_file() {
        return Err(err(
            "no such file. Make one on a machine with torchvision: python -c \"import torch, torchvision; \
             torch.save(torchvision.models.resnet18(weights='IMAGENET1K_V1').state_dict(), 'resnet18.pth')\""
                .into(),
        ));
    }
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let named = match ext.as_str() {
        "safetensors" => Tensor::read_safetensors(path).map_err(|e| err(format!("cannot read it: {e}")))?,
        "pt" | "pth" | "bin" => {
            crate::net::pth::read_state_dict(path).map_err(|e| err(format!("cannot read it: {e}")))?
        }
        _ => return Err(err(format!("unknown extension `.{ext}`: use .safetensors, .pt or .pth"))),
    };
    // DataParallel checkpoints prefix every name with `module.`.
    Ok(named.into_iter().map(|(k, v)| (k.strip_prefix("module.").map(str::to_string).unwrap_or(k), v)).collect())
}

/// Copies torchvision weights into the variables of `vs` whose names start with `prefix`
/// (`prefix` + torchvision name). Every trunk variable must be in the file with the same shape;
/// the classifier (`fc.*`) and `num_batches_tracked` are ignored. Returns how many were copied.
pub fn load_torchvision(vs: &nn::VarStore, prefix: &str, path: &Path) -> Result<usize, WeightsError> {
    let named = read_torchvision(path)?;
    let err = |reason: String| WeightsError { file: path.display().to_string(), reason };
    let vars = vs.variables();
    let mut wanted: Vec<(&String, &Tensor)> = vars.iter().filter(|(k, _)| k.starts_with(prefix)).collect();
    wanted.sort_by(|a, b| a.0.cmp(b.0));
    if wanted.is_empty() {
        return Err(err(format!("the network has no variables under `{prefix}`")));
    }
    let missing: Vec<&str> =
        wanted.iter().map(|(k, _)| &k[prefix.len()..]).filter(|k| !named.contains_key(*k)).collect();
    if !missing.is_empty() {
        let show: Vec<&str> = missing.iter().take(5).copied().collect();
        return Err(err(format!(
            "not a torchvision ResNet-18 state dict: {} tensor(s) missing, e.g. {}",
            missing.len(),
            show.join(", ")
        )));
    }
    tch::no_grad(|| {
        for (name, var) in &wanted {
            let src = &named[&name[prefix.len()..]];
            if src.size() != var.size() {
                return Err(err(format!(
                    "`{}` has shape {:?}, ResNet-18 needs {:?}",
                    &name[prefix.len()..],
                    src.size(),
                    var.size()
                )));
            }
            let mut dst = (*var).shallow_clone();
            dst.copy_(&src.to_kind(var.kind()).to_device(var.device()));
        }
        Ok(())
    })?;
    Ok(wanted.len())
}

/// Loads a checkpoint into a fresh ResNet-18 as the frozen encoder would, and runs it once:
/// a check to make before a long run. Returns a one-line summary.
pub fn check_weights(path: &Path) -> Result<String, WeightsError> {
    let vs = nn::VarStore::new(Device::Cpu);
    // its draws are overwritten; `seeded` keeps them from another thread's sequence
    let net = crate::device::seeded(0, || Resnet18::new(&vs.root()));
    let n = load_torchvision(&vs, "", path)?;
    let x = imagenet_normalize(&Tensor::full([1, 3, 224, 224], 0.5, (Kind::Float, Device::Cpu)));
    let y = tch::no_grad(|| net.forward(&x));
    if y.isfinite().all().int64_value(&[]) == 0 {
        return Err(WeightsError { file: path.display().to_string(), reason: "conv5 output is not finite".into() });
    }
    Ok(format!(
        "{}: {n} ResNet-18 tensors loaded; conv5 of a grey 224x224 image: {:?}, mean {:.4}",
        path.display(),
        y.size(),
        y.mean(Kind::Float).double_value(&[])
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The folded trunk, its weights from `fold_batch_norms`, gives what the trunk with its batch
    /// norms gives (f32, every norm's statistics and affine map drawn at random), at the stem's
    /// name without a prefix and under one.
    #[test]
    fn a_folded_trunk_equals_the_trunk_with_its_norms() {
        for prefix in [None, Some("resnet")] {
            let (vs, folded_vs) = (nn::VarStore::new(Device::Cpu), nn::VarStore::new(Device::Cpu));
            fn at<'a>(v: &'a nn::VarStore, prefix: Option<&str>) -> nn::Path<'a> {
                match prefix {
                    Some(p) => v.root() / p,
                    None => v.root(),
                }
            }
            let (net, folded, x) = crate::device::seeded(9, || {
                let net = Resnet18::new(&at(&vs, prefix));
                tch::no_grad(|| {
                    for (k, mut v) in vs.variables() {
                        if v.dim() == 1 {
                            let r = Tensor::rand_like(&v);
                            v.copy_(&if k.ends_with("running_var") { r + 0.5 } else { r - 0.5 });
                        }
                    }
                });
                (
                    net,
                    Resnet18::folded(&at(&folded_vs, prefix)),
                    Tensor::randn([2, 3, 64, 64], (Kind::Float, Device::Cpu)),
                )
            });
            let src = vs.variables();
            tch::no_grad(|| {
                for (name, mut dst) in folded_vs.variables() {
                    dst.copy_(&fold_batch_norms(&src, &name));
                }
            });
            let (want, got) = tch::no_grad(|| (net.forward(&x), folded.forward(&x)));
            let scale = want.abs().max().double_value(&[]);
            let err = (&want - &got).abs().max().double_value(&[]);
            assert!(err < 1e-4 * scale.max(1.0), "{prefix:?}: error {err} against {scale}");
        }
    }

    #[test]
    fn conv5_is_7x7_for_224_and_2x2_for_64() {
        assert_eq!(conv5_side(224), 7);
        assert_eq!(conv5_side(64), 2);
        let vs = nn::VarStore::new(Device::Cpu);
        let (net, x) = crate::device::seeded(4, || {
            (Resnet18::new(&vs.root()), Tensor::randn([1, 3, 64, 64], (Kind::Float, Device::Cpu)))
        });
        let y = tch::no_grad(|| net.forward(&x));
        assert_eq!(y.size(), vec![1, 512, 2, 2]);
        // 11.2M parameters in the trunk (torchvision's 11.69M minus the 513k of fc)
        let params: i64 = vs.trainable_variables().iter().map(|t| t.numel() as i64).sum();
        assert_eq!(params, 11_176_512);
    }

    /// Writes a torchvision-named checkpoint (with the classifier and `num_batches_tracked`, as
    /// torchvision has them), loads it into a fresh trunk, and compares conv5 outputs.
    #[test]
    fn torchvision_checkpoint_loads_into_a_fresh_trunk() {
        let a = nn::VarStore::new(Device::Cpu);
        let net_a = crate::device::seeded(3, || Resnet18::new(&a.root()));
        let mut named: Vec<(String, Tensor)> = Vec::new();
        // every draw from torch's one generator under `seeded`: tests run side by side
        crate::device::seeded(9, || {
            tch::no_grad(|| {
                for (k, v) in a.variables() {
                    // non-trivial batch-norm statistics and weights, so a wrong mapping shows
                    let mut v = v;
                    if k.ends_with("running_var") {
                        v.copy_(&(Tensor::rand_like(&v) + 0.5));
                    } else if k.contains("bn") || k.contains("downsample.1") {
                        v.copy_(&(Tensor::randn_like(&v) * 0.1 + if k.ends_with("weight") { 1.0 } else { 0.0 }));
                    }
                    named.push((k.clone(), v.copy()));
                    if k.ends_with("running_var") {
                        named.push((k.replace("running_var", "num_batches_tracked"), Tensor::from(7i64)));
                    }
                }
            })
        });
        named.push(("fc.weight".into(), Tensor::zeros([1000, 512], (Kind::Float, Device::Cpu))));
        named.push(("fc.bias".into(), Tensor::zeros([1000], (Kind::Float, Device::Cpu))));
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("resnet18.safetensors");
        Tensor::write_safetensors(&named, &file).unwrap();

        // and the same as torch.save(model.state_dict()) writes it
        let pth = dir.path().join("resnet18.pth");
        let refs: Vec<(&str, Tensor)> = named.iter().map(|(k, v)| (k.as_str(), v.shallow_clone())).collect();
        crate::net::pth::tests::write_torch_save(&pth, &refs);

        let x = crate::device::seeded(5, || Tensor::rand([2, 3, 64, 64], (Kind::Float, Device::Cpu)));
        let ya = tch::no_grad(|| net_a.forward(&x));
        assert!(ya.abs().sum(Kind::Float).double_value(&[]) > 0.0);
        for f in [&file, &pth] {
            let b = nn::VarStore::new(Device::Cpu);
            let net_b = crate::device::seeded(10, || Resnet18::new(&(b.root() / "enc")));
            let n = load_torchvision(&b, "enc.", f).unwrap();
            // 20 convolutions + 20 batch norms × (weight, bias, running mean, running var)
            assert_eq!(n, 100);
            let yb = tch::no_grad(|| net_b.forward(&x));
            assert!(ya.allclose(&yb, 1e-5, 1e-5, false), "{}", f.display());
        }
        assert!(check_weights(&pth).unwrap().contains("100 ResNet-18 tensors"));
    }

    #[test]
    fn wrong_or_missing_files_name_the_file_and_the_tensor() {
        let dir = tempfile::tempdir().unwrap();
        let vs = nn::VarStore::new(Device::Cpu);
        let _net = Resnet18::new(&(vs.root() / "enc"));
        let missing = dir.path().join("nope.pth");
        let e = load_torchvision(&vs, "enc.", &missing).unwrap_err().to_string();
        assert!(e.contains("nope.pth") && e.contains("no such file"), "{e}");

        let other = dir.path().join("other.safetensors");
        let t = Tensor::zeros([3], (Kind::Float, Device::Cpu));
        Tensor::write_safetensors(&[("conv1.weight", &t)], &other).unwrap();
        let e = load_torchvision(&vs, "enc.", &other).unwrap_err().to_string();
        assert!(e.contains("other.safetensors") && e.contains("missing"), "{e}");

        let junk = dir.path().join("junk.safetensors");
        std::fs::write(&junk, b"not a checkpoint").unwrap();
        let e = load_torchvision(&vs, "enc.", &junk).unwrap_err().to_string();
        assert!(e.contains("junk.safetensors") && e.contains("cannot read"), "{e}");
    }
}
