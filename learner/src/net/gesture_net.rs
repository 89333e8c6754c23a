//! The gesture network: a gesture's 100 frames `[B, 100, d]` → one feature `[B, hidden]`.
//!
//! ```text
//! flat (§4.3.3):  100×d ─ flatten ─ FC hidden ─ ReLU
//! per_frame:      each frame d ─ FC 64 ─ ReLU ─ FC 64 ─ ReLU ┐ mean and max over the 100 frames
//!                                                            └ 128 ─ FC hidden ─ ReLU
//! flat_and_per_frame: the two side by side, hidden/2 each, concatenated (the pose, if any,
//!                 read by the per-frame half only)
//! ```
//! The flat layer gives each frame its own weights: a pointing held in frames 40–60 and the same
//! pointing in frames 50–70 are different inputs to learn, each from PPO's gradient alone. The
//! per-frame network reads every frame with the same small weights and pools over time, so a
//! pose held anywhere in the gesture is one thing to learn (beyond the dissertation). With
//! `model.person_pose` each frame carries the person's pose too (`NetSpec::pose_in_frames`), so
//! the arm's direction in the person's frame can be turned by their facing frame by frame — the
//! gesture probe's per-frame column (docs/encoder).
//!
//! The pose is the same in all 100 frames and changes at every step, the gesture only when an
//! episode starts or intervention switches: the first layer on `[frame, pose]` is computed as its
//! gesture part once per distinct gesture plus its pose part once per row ([`GestureNet::read`]),
//! not over 100 concatenated frames per row.

use farm::config::GestureNetwork;
use shm_schema::GESTURE_FRAMES;
use tch::{Kind, Tensor, nn};

/// Width of the per-frame network's layers.
const FRAME_WIDTH: i64 = 64;

/// The gesture network; its variables live under `gesture.`.
#[derive(Debug)]
pub(crate) enum GestureNet {
    Flat(nn::Linear),
    PerFrame(PerFrame),
    FlatAndPerFrame(nn::Linear, PerFrame),
}

/// The shared per-frame network and its layer from the pooled frames to the feature.
#[derive(Debug)]
pub(crate) struct PerFrame {
    frame: [nn::Linear; 2],
    out: nn::Linear,
}

impl GestureNet {
    /// `dims` gesture values per frame (and `pose_dims` of the pose beside each, read by the
    /// per-frame network) → `hidden`, initialised from torch's seed.
    pub(crate) fn new(p: &nn::Path, kind: GestureNetwork, dims: i64, pose_dims: i64, hidden: i64) -> GestureNet {
        let flat = |p: &nn::Path, width| nn::linear(p, GESTURE_FRAMES as i64 * dims, width, Default::default());
        match kind {
            GestureNetwork::Flat => GestureNet::Flat(flat(p, hidden)),
            GestureNetwork::PerFrame => GestureNet::PerFrame(PerFrame::new(p, dims + pose_dims, hidden)),
            GestureNetwork::FlatAndPerFrame => GestureNet::FlatAndPerFrame(
                flat(&(p / "flat"), hidden / 2),
                PerFrame::new(p, dims + pose_dims, hidden - hidden / 2),
            ),
        }
    }

    /// Gestures `[B, 100, d]` (any float kind) → features `[B, hidden]` in f32.
    pub(crate) fn forward(&self, g: &Tensor) -> Tensor {
        self.read(g, None, None)
    }

    /// Features `[R, hidden]` of `R` rows: with `rows` (i64 `[R]`), `g` holds distinct gestures
    /// `[G, 100, d]` and row `r` shows `g[rows[r]]`; without, `g` is `[R, 100, d]`. With `pose`
    /// (`[R, 4]`, the per-frame network only) each row's frames are read with its person's pose
    /// beside them — the last 4 inputs of the first layer — where a gesture is shown (an unshown
    /// gesture is all zero, and so is what the network reads then).
    pub(crate) fn read(&self, g: &Tensor, rows: Option<&Tensor>, pose: Option<&Tensor>) -> Tensor {
        let g = g.to_kind(Kind::Float);
        // fewer rows than distinct gestures (one that changes at every step, as keypoints seen
        // from a moving robot): gathered, then read row by row
        let (g, rows) = match rows {
            Some(i) if g.size()[0] > i.numel() as i64 => (g.index_select(0, i), None),
            r => (g, r),
        };
        let flat = |l: &nn::Linear| gather(g.flatten(1, -1).apply(l).relu(), rows);
        match self {
            GestureNet::Flat(l) => {
                assert!(pose.is_none(), "the flat layer reads the pose as its own input");
                flat(l)
            }
            GestureNet::PerFrame(f) => f.read(&g, rows, pose),
            GestureNet::FlatAndPerFrame(l, f) => Tensor::cat(&[flat(l), f.read(&g, rows, pose)], 1),
        }
    }

    /// Width of the features.
    pub(crate) fn hidden(&self) -> i64 {
        match self {
            GestureNet::Flat(l) => l.ws.size()[0],
            GestureNet::PerFrame(f) => f.out.ws.size()[0],
            GestureNet::FlatAndPerFrame(l, f) => l.ws.size()[0] + f.out.ws.size()[0],
        }
    }

    /// Version counters of every variable: they change when the optimizer or a checkpoint load
    /// writes the weights in place (acting's memo recomputes then).
    pub(crate) fn versions(&self) -> Vec<i64> {
        self.layers()
            .iter()
            .flat_map(|l| [Some(&l.ws), l.bs.as_ref()])
            .map(|v| v.map_or(0, |v| v.internal_version()))
            .collect()
    }

    fn layers(&self) -> Vec<&nn::Linear> {
        match self {
            GestureNet::Flat(l) => vec![l],
            GestureNet::PerFrame(f) => f.layers(),
            GestureNet::FlatAndPerFrame(l, f) => [vec![l], f.layers()].concat(),
        }
    }
}

impl PerFrame {
    fn new(p: &nn::Path, dims: i64, hidden: i64) -> PerFrame {
        let c = Default::default;
        PerFrame {
            frame: [
                nn::linear(p / "frame0", dims, FRAME_WIDTH, c()),
                nn::linear(p / "frame1", FRAME_WIDTH, FRAME_WIDTH, c()),
            ],
            out: nn::linear(p / "out", 2 * FRAME_WIDTH, hidden, c()),
        }
    }

    /// [`GestureNet::read`] for this network, on f32 gestures (gathered first where the rows are
    /// fewer).
    fn read(&self, g: &Tensor, rows: Option<&Tensor>, pose: Option<&Tensor>) -> Tensor {
        let [first, _] = &self.frame;
        match pose {
            None => gather(self.after_first(g.apply(first)), rows),
            Some(pose) => {
                // frame0([frame, pose]) = W_g·frame + b, once per gesture, + W_p·pose, once per row
                let d = g.size()[2];
                let gesture = g.linear(&first.ws.narrow(1, 0, d), first.bs.as_ref());
                let shown = g.ne(0.0).flatten(1, -1).any_dim(1, true).to_kind(Kind::Float);
                let pose = pose.linear::<Tensor>(&first.ws.narrow(1, d, pose.size()[1]), None) * gather(shown, rows);
                self.after_first(gather(gesture, rows) + pose.unsqueeze(1))
            }
        }
    }

    /// From the first layer's output `[R, 100, 64]` on.
    fn after_first(&self, first: Tensor) -> Tensor {
        let f = first.relu().apply(&self.frame[1]).relu();
        let pooled = Tensor::cat(&[f.mean_dim(1, false, Kind::Float), f.amax(1, false)], 1);
        pooled.apply(&self.out).relu()
    }

    fn layers(&self) -> Vec<&nn::Linear> {
        vec![&self.frame[0], &self.frame[1], &self.out]
    }
}

/// Row `r` of the result is `t[rows[r]]`; without `rows`, `t` itself.
fn gather(t: Tensor, rows: Option<&Tensor>) -> Tensor {
    match rows {
        Some(i) => t.index_select(0, i),
        None => t,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    /// The per-frame network reads what the frames show, not when: a pose held in other frames
    /// gives the same features (the flat layer's differ).
    #[test]
    fn per_frame_features_do_not_depend_on_when_a_pose_is_held() {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = crate::device::seeded(1, || GestureNet::new(&vs.root(), GestureNetwork::PerFrame, 30, 0, 16));
        let rest = crate::device::seeded(2, || Tensor::randn([1, 1, 30], (Kind::Float, Device::Cpu)));
        let pointing = crate::device::seeded(3, || Tensor::randn([1, 1, 30], (Kind::Float, Device::Cpu)));
        let frames = GESTURE_FRAMES as i64;
        let held = |from: i64| {
            let g = rest.expand([1, frames, 30], false).copy();
            g.narrow(1, from, 20).copy_(&pointing.expand([1, 20, 30], false));
            g
        };
        let (early, late) = tch::no_grad(|| (net.forward(&held(10)), net.forward(&held(70))));
        assert_eq!(early.size(), [1, 16]);
        assert!(early.allclose(&late, 1e-5, 1e-6, false), "{early} vs {late}");
        let still = tch::no_grad(|| net.forward(&rest.expand([1, frames, 30], false)));
        assert!(!early.allclose(&still, 1e-3, 1e-3, false), "the held pose must show");
        // the flat layer tells them apart
        let flat = crate::device::seeded(1, || GestureNet::new(&(vs.root() / "flat"), GestureNetwork::Flat, 30, 0, 16));
        let (a, b) = tch::no_grad(|| (flat.forward(&held(10)), flat.forward(&held(70))));
        assert!(!a.allclose(&b, 1e-3, 1e-3, false));
    }

    /// The pose read beside the frames (the split first layer) is the pose read in them: the
    /// features and gradients of concatenating it to every frame of a shown gesture (an unshown,
    /// all-zero gesture reads none), whether the rows are read through their distinct gestures
    /// or one by one.
    #[test]
    fn the_pose_beside_the_frames_reads_as_the_pose_in_them() {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = crate::device::seeded(1, || GestureNet::new(&vs.root(), GestureNetwork::PerFrame, 5, 4, 8));
        let distinct =
            crate::device::seeded(2, || Tensor::randn([3, GESTURE_FRAMES as i64, 5], (Kind::Float, Device::Cpu)));
        let _ = distinct.get(2).zero_();
        let pose = crate::device::seeded(3, || Tensor::randn([5, 4], (Kind::Float, Device::Cpu)));
        let rows = Tensor::from_slice(&[0i64, 2, 1, 0, 2]);
        let shown = Tensor::from_slice(&[1f32, 0.0, 1.0, 1.0, 0.0]).view([5, 1, 1]);
        let frames = pose.unsqueeze(1).expand([5, GESTURE_FRAMES as i64, 4], false) * shown;
        let read = |f: &dyn Fn() -> Tensor| {
            vs.trainable_variables().iter_mut().for_each(|v| v.zero_grad());
            let out = f();
            out.square().sum(Kind::Float).backward();
            (out.detach(), vs.trainable_variables().iter().map(|v| v.grad().copy()).collect::<Vec<_>>())
        };
        let g = distinct.index_select(0, &rows);
        let (want, want_grads) = read(&|| net.forward(&Tensor::cat(&[&g, &frames], 2)));
        for (name, got) in [
            ("distinct", read(&|| net.read(&distinct, Some(&rows), Some(&pose)))),
            ("one by one", read(&|| net.read(&g, None, Some(&pose)))),
        ] {
            assert!(got.0.allclose(&want, 1e-5, 1e-6, false), "{name}: {} vs {want}", got.0);
            for (a, b) in got.1.iter().zip(&want_grads) {
                assert!(a.allclose(b, 1e-4, 1e-6, false), "{name}: gradients differ");
            }
        }
        // fewer rows than distinct gestures: gathered first, the same features
        let one = Tensor::from_slice(&[1i64]);
        let few = tch::no_grad(|| net.read(&distinct, Some(&one), Some(&pose.narrow(0, 2, 1))));
        assert!(few.allclose(&want.narrow(0, 2, 1), 1e-5, 1e-6, false));
    }

    #[test]
    fn widths_and_variable_names() {
        let vs = nn::VarStore::new(Device::Cpu);
        let flat = GestureNet::new(&(vs.root() / "gesture"), GestureNetwork::Flat, 95, 0, 32);
        let per = GestureNet::new(&(vs.root() / "other"), GestureNetwork::PerFrame, 95, 0, 32);
        let both = GestureNet::new(&(vs.root() / "both"), GestureNetwork::FlatAndPerFrame, 95, 4, 32);
        assert_eq!((flat.hidden(), per.hidden(), both.hidden()), (32, 32, 32));
        let v = vs.variables();
        assert_eq!(v["gesture.weight"].size(), [32, 100 * 95], "§4.3.3's layer, as checkpoints name it");
        assert_eq!(v["other.frame0.weight"].size(), [64, 95]);
        assert_eq!(v["other.out.weight"].size(), [32, 128]);
        assert_eq!(per.versions().len(), 6);
        // side by side: the flat half reads the gesture alone, the per-frame half the pose too
        assert_eq!(v["both.flat.weight"].size(), [16, 100 * 95]);
        assert_eq!(v["both.frame0.weight"].size(), [64, 95 + 4]);
        assert_eq!(v["both.out.weight"].size(), [16, 128]);
        assert_eq!(both.versions().len(), 8);
    }
}
