//! A frozen visual encoder for CPU runs, pretrained without labels on frames of the training
//! rooms (DESIGN §6): the role ImageNet plays for the dissertation's ResNet-18.
//!
//! - [`net`]: the early-fusion RGB-D trunk, its input and its weights file
//! - [`pretrain`]: `learner pretrain-encoder`: dense contrast or reconstruction (label-free), or
//!   the semantic sensor (per-cell class and depth); the contrast also for configs/faithful's
//!   ResNet-18 where no ImageNet checkpoint is supplied
//! - [`probe`]: `learner probe-encoder`: linear probes of the category per cell and the person's
//!   facing, in held-out rooms

pub mod net;
pub mod pretrain;
pub mod probe;

pub use net::{EncoderFileError, EncoderInfo, RgbdEncoder, encoder_input, load_weights};
pub use pretrain::{Objective, PretrainOptions, PretrainReport, Trunk, pretrain};
pub use probe::{ProbeOptions, ProbeReport, probe};

#[cfg(test)]
mod tests {
    use farm::frame_set::{CLASSES, FrameRef, FrameSet, FrameSetHeader};
    use rand::Rng;

    use super::*;

    /// A random 16×16 frame set with 2×2 cells (random labels: enough to check the report).
    fn synthetic(dir: &std::path::Path, n: usize) -> std::path::PathBuf {
        synthetic_of(dir, n, 16)
    }

    /// The same at `side`² pixels.
    fn synthetic_of(dir: &std::path::Path, n: usize, side: u32) -> std::path::PathBuf {
        let header =
            FrameSetHeader { width: side, height: side, grid: 2, classes: CLASSES, seed: 5, held_out: vec![19] };
        let mut set = FrameSet::new(header).unwrap();
        let mut r = farm::seed::rng(5, &[]);
        let px = (side * side) as usize;
        for i in 0..n {
            let rgb: Vec<u8> = (0..px * 3).map(|_| r.random()).collect();
            let depth: Vec<u16> = (0..px).map(|_| r.random()).collect();
            let class: Vec<u8> = (0..4).map(|_| r.random_range(0..3)).collect();
            let room = if i % 8 == 0 { 19 } else { 1 + (i % 5) as u16 };
            set.push(&FrameRef {
                room,
                flags: 0,
                person_facing: f32::NAN,
                rgb: &rgb,
                depth: &depth,
                cell_class: &class,
                cell_depth: &[100; 4],
            })
            .unwrap();
        }
        let p = dir.join("syn.frames");
        set.write(&p).unwrap();
        p
    }

    /// The report names the weights it wrote. That the same seed gives the same weights is
    /// checked in `tests/encoder.rs`, one process per run: here other tests share torch's global
    /// generator and thread count, so only "another seed, other weights" holds.
    #[test]
    fn the_report_describes_the_weights_written() {
        let dir = tempfile::tempdir().unwrap();
        let frames = synthetic(dir.path(), 64);
        let run = |name: &str, seed: u64| {
            let o = PretrainOptions::new(frames.clone(), dir.path().join(name), seed, 1);
            pretrain(&o, tch::Device::Cpu).unwrap()
        };
        let (a, c) = (run("a", 3), run("c", 4));
        assert_ne!(a.sha256, c.sha256);
        assert_eq!(a.held_out_frames, 8);
        assert_eq!(a.held_out_rooms, vec!["FloorPlan19"]);
        let bytes = std::fs::read(dir.path().join("a.safetensors")).unwrap();
        assert_eq!(net::sha256_hex(&bytes), a.sha256);
        let json: PretrainReport =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join("a.json")).unwrap()).unwrap();
        assert_eq!(json.sha256, a.sha256);
    }

    #[test]
    fn unusable_frame_sets_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let header = FrameSetHeader { width: 16, height: 16, grid: 2, classes: 3, seed: 5, held_out: vec![] };
        let p = dir.path().join("few.frames");
        FrameSet::new(header).unwrap().write(&p).unwrap();
        let mut o = PretrainOptions::new(p, dir.path().join("x"), 1, 1);
        let e = pretrain(&o, tch::Device::Cpu).unwrap_err();
        assert!(e.to_string().contains("few.frames") && e.to_string().contains("no frames"), "{e}");
        o.objective = Objective::Semantic;
        let e = pretrain(&o, tch::Device::Cpu).unwrap_err();
        assert!(e.to_string().contains("few.frames") && e.to_string().contains("classes"), "{e}");
    }

    /// Each objective reports its own held-out figures (that reconstruction reads no label is
    /// checked in `tests/encoder.rs`, one process per run).
    #[test]
    fn each_objective_reports_its_figures() {
        let dir = tempfile::tempdir().unwrap();
        let frames = synthetic(dir.path(), 32);
        let run = |name: &str, objective: Objective| {
            let mut o = PretrainOptions::new(frames.clone(), dir.path().join(name), 3, 1);
            o.objective = objective;
            pretrain(&o, tch::Device::Cpu).unwrap()
        };
        let a = run("a", Objective::Reconstruct);
        assert!(a.held_out.rgb_error.is_some() && a.held_out.accuracy.is_none(), "{:?}", a.held_out);
        assert_eq!((a.objective, a.mask), (Objective::Reconstruct, 0.0));
        let b = run("b", Objective::Contrast);
        assert!(b.held_out.cells_matched.is_some_and(|m| (0.0..=1.0).contains(&m)), "{:?}", b.held_out);
        let c = run("c", Objective::Semantic);
        assert!(c.held_out.accuracy.is_some() && c.held_out.rgb_error.is_none(), "{:?}", c.held_out);
        assert_eq!(c.objective, Objective::Semantic);
    }

    /// configs/faithful's label-free trunk: the file holds every tensor of the frozen ResNet-18
    /// with torchvision's names (what `model.resnet_weights` loads), trained (not the 0-epoch
    /// trunk), and is refused as an RGB-D encoder; only the contrast pretrains it.
    #[test]
    fn a_resnet_trunk_is_written_for_the_faithful_config() {
        use crate::net::resnet;
        let dir = tempfile::tempdir().unwrap();
        let frames = synthetic_of(dir.path(), 16, 64);
        let mut o = PretrainOptions::new(frames, dir.path().join("r18"), 3, 1);
        (o.trunk, o.batch) = (Trunk::Resnet18, 8);
        let r = pretrain(&o, tch::Device::Cpu).unwrap();
        assert_eq!((r.trunk, r.in_channels, r.feature_channels), (Trunk::Resnet18, 3, 512));
        assert!(r.held_out.cells_matched.is_some_and(|m| (0.0..=1.0).contains(&m)), "{:?}", r.held_out);
        let file = dir.path().join("r18.safetensors");
        let vs = tch::nn::VarStore::new(tch::Device::Cpu);
        let _trunk = resnet::Resnet18::new(&(vs.root() / "resnet"));
        assert_eq!(resnet::load_torchvision(&vs, "resnet.", &file).unwrap(), 100);
        assert!(resnet::check_weights(&file).unwrap().contains("100 ResNet-18 tensors"));
        let e = load_weights(&file, &vs, "encoder", (64, 64)).unwrap_err().to_string();
        assert!(e.contains("r18.safetensors") && e.contains("resnet_weights"), "{e}");

        let untrained = PretrainOptions { out: dir.path().join("r18-0"), epochs: 0, ..o.clone() };
        assert_ne!(pretrain(&untrained, tch::Device::Cpu).unwrap().sha256, r.sha256);
        o.objective = Objective::Semantic;
        let e = pretrain(&o, tch::Device::Cpu).unwrap_err().to_string();
        assert!(e.contains("ResNet-18") && e.contains("contrast objective only"), "{e}");
    }
}
