//! The gesture network: a gesture's 100 frames `[B, 100, d]` → one feature `[B, hidden]`.
//!
//! ```text
//! flat (§4.3.3):   100×d ─ flatten ─ FC hidden ─ ReLU
//! flat_and_turned: the flat layer (hidden/2) beside a network shared by every frame:
//!                  each frame d ─ FC 64 ─ ReLU ─ FC 64 ─ ReLU ┐ mean and max over the 100 frames
//!                  = p (128); the person's pose joins p: ReLU(A·p + shown·(cos·B·p + sin·C·p + D·pose))
//! ```
//! The flat layer gives each frame its own weights: a pointing held in frames 40–60 and the same
//! pointing in frames 50–70 are different inputs to learn, each from PPO's gradient alone. The
//! per-frame network reads every frame with the same small weights and pools over time, so a
//! pose held anywhere in the gesture is one thing to learn (beyond the dissertation).
//!
//! A pointing is a direction in the person's own frame (the muscles); it names a place for the
//! robot only once turned by the person's facing relative to it. With `model.person_pose` the
//! pose joins after the pooling: cos·B·p + sin·C·p is any linear reading of p turned by the
//! facing, D·pose says where the person stands. The pose changes at every step and the gesture
//! only when an episode starts or intervention switches, so the 100 frames are read once per
//! distinct gesture ([`GestureNet::part`]) and the pose joins per row in one layer
//! ([`GestureNet::join`]).

use farm::config::GestureNetwork;
use shm_schema::GESTURE_FRAMES;
use tch::{Kind, Tensor, nn};

/// Width of the per-frame network's layers.
const FRAME_WIDTH: i64 = 64;

/// The gesture network; its variables live under `gesture.`.
#[derive(Debug)]
pub(crate) enum GestureNet {
    Flat(nn::Linear),
    FlatAndTurned(nn::Linear, Turned),
}

/// The network shared by every frame and its layer from the pooled frames to the feature (A).
#[derive(Debug)]
pub(crate) struct PerFrame {
    frame: [nn::Linear; 2],
    out: nn::Linear,
}

/// The per-frame network on the gesture alone, its pooled values turned by the person's facing
/// and joined by where they stand (`flat_and_turned`).
#[derive(Debug)]
pub(crate) struct Turned {
    frames: PerFrame,
    /// B and C, `128 → 2 × width`, and D, `pose → width` (none without the pose).
    turn_and_place: Option<(nn::Linear, nn::Linear)>,
}

impl GestureNet {
    /// `dims` gesture values per frame (and `pose_dims` of the person's pose, joined after the
    /// pooling) → `hidden`, initialised from torch's seed.
    pub(crate) fn new(p: &nn::Path, kind: GestureNetwork, dims: i64, pose_dims: i64, hidden: i64) -> GestureNet {
        let flat = |p: &nn::Path, width| nn::linear(p, GESTURE_FRAMES as i64 * dims, width, Default::default());
        match kind {
            GestureNetwork::Flat => GestureNet::Flat(flat(p, hidden)),
            GestureNetwork::FlatAndTurned => GestureNet::FlatAndTurned(
                flat(&(p / "flat"), hidden / 2),
                Turned::new(p, dims, pose_dims, hidden - hidden / 2),
            ),
        }
    }

    /// Features `[R, hidden]` of `R` rows: with `rows` (i64 `[R]`), `g` holds distinct gestures
    /// `[G, 100, d]` and row `r` shows `g[rows[r]]`; without, `g` is `[R, 100, d]`. With `pose`
    /// (`[R, 4]`: right, forward, cos and sin of the facing) each row's gesture is read with its
    /// person's pose where a gesture is shown (an unshown gesture is all zero, and reads no pose).
    pub(crate) fn read(&self, g: &Tensor, rows: Option<&Tensor>, pose: Option<&Tensor>) -> Tensor {
        self.join(&gather(self.part(g), rows), pose)
    }

    /// What the network reads of gestures `[G, 100, d]` alone, `[G, part_width]` f32: the
    /// features themselves, or with `flat_and_turned` what the pose joins ([`GestureNet::join`]).
    pub(crate) fn part(&self, g: &Tensor) -> Tensor {
        let g = g.to_kind(Kind::Float);
        match self {
            GestureNet::Flat(l) => flat(l, &g),
            GestureNet::FlatAndTurned(l, t) => Tensor::cat(&[flat(l, &g), t.part(&g)], 1),
        }
    }

    /// Parts of `R` rows (`[R, part_width]`, [`GestureNet::part`]) and their person's pose
    /// (`[R, 4]`, `flat_and_turned` only) → features `[R, hidden]`.
    pub(crate) fn join(&self, part: &Tensor, pose: Option<&Tensor>) -> Tensor {
        match self {
            GestureNet::FlatAndTurned(l, t) => {
                let h = l.ws.size()[0];
                let rest = part.size()[1] - h;
                Tensor::cat(&[part.narrow(1, 0, h), t.join(&part.narrow(1, h, rest), pose)], 1)
            }
            GestureNet::Flat(_) => part.shallow_clone(),
        }
    }

    /// Width of [`GestureNet::part`].
    pub(crate) fn part_width(&self) -> i64 {
        match self {
            GestureNet::FlatAndTurned(l, t) => l.ws.size()[0] + t.part_width(),
            GestureNet::Flat(_) => self.hidden(),
        }
    }

    /// Width of the features.
    pub(crate) fn hidden(&self) -> i64 {
        match self {
            GestureNet::Flat(l) => l.ws.size()[0],
            GestureNet::FlatAndTurned(l, t) => l.ws.size()[0] + t.frames.out.ws.size()[0],
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
            GestureNet::FlatAndTurned(l, t) => [vec![l], t.layers()].concat(),
        }
    }
}

/// The flat layer on f32 gestures `[G, 100, d]`.
fn flat(l: &nn::Linear, g: &Tensor) -> Tensor {
    g.flatten(1, -1).apply(l).relu()
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

    /// The pooled `[G, 128]` of gestures `[G, 100, d]`: mean and max over the frames.
    fn pooled(&self, g: &Tensor) -> Tensor {
        let f = g.apply(&self.frame[0]).relu().apply(&self.frame[1]).relu();
        Tensor::cat(&[f.mean_dim(1, false, Kind::Float), f.amax(1, false)], 1)
    }

    fn layers(&self) -> Vec<&nn::Linear> {
        vec![&self.frame[0], &self.frame[1], &self.out]
    }
}

impl Turned {
    fn new(p: &nn::Path, dims: i64, pose_dims: i64, width: i64) -> Turned {
        let no_bias = || nn::LinearConfig { bias: false, ..Default::default() };
        // B, C and D are drawn before the per-frame layers: checkpoints' initial weights follow
        // this order
        let turn_and_place = (pose_dims > 0).then(|| {
            (
                nn::linear(p / "turn", 2 * FRAME_WIDTH, 2 * width, no_bias()),
                nn::linear(p / "place", pose_dims, width, no_bias()),
            )
        });
        Turned { frames: PerFrame::new(p, dims, width), turn_and_place }
    }

    /// `[A·p + b, B·p, C·p, shown]` of gestures `[G, 100, d]` (A·p + b alone without the pose).
    fn part(&self, g: &Tensor) -> Tensor {
        let p = self.frames.pooled(g);
        let a = p.apply(&self.frames.out);
        match &self.turn_and_place {
            Some((turn, _)) => Tensor::cat(&[a, p.apply(turn), shown(g)], 1),
            None => a,
        }
    }

    fn part_width(&self) -> i64 {
        let w = self.frames.out.ws.size()[0];
        if self.turn_and_place.is_some() { 3 * w + 1 } else { w }
    }

    /// ReLU(A·p + b + shown·(cos·B·p + sin·C·p + D·pose)); without a pose, ReLU(A·p + b).
    fn join(&self, part: &Tensor, pose: Option<&Tensor>) -> Tensor {
        let w = self.frames.out.ws.size()[0];
        let a = part.narrow(1, 0, w);
        match (&self.turn_and_place, pose) {
            (Some((_, place)), Some(pose)) => {
                let (b, c, shown) = (part.narrow(1, w, w), part.narrow(1, 2 * w, w), part.narrow(1, 3 * w, 1));
                let turned = b * pose.narrow(1, 2, 1) + c * pose.narrow(1, 3, 1) + pose.apply(place);
                (a + shown * turned).relu()
            }
            _ => a.relu(),
        }
    }

    fn layers(&self) -> Vec<&nn::Linear> {
        let mut l = self.frames.layers();
        if let Some((turn, place)) = &self.turn_and_place {
            l.extend([turn, place]);
        }
        l
    }
}

/// `[G, 1]`: 1 where gesture `g` is shown (not all zero), f32.
fn shown(g: &Tensor) -> Tensor {
    g.ne(0.0).flatten(1, -1).any_dim(1, true).to_kind(Kind::Float)
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

    /// The per-frame half reads what the frames show, not when: a pose held in other frames
    /// gives the same features; the flat half tells them apart.
    #[test]
    fn per_frame_features_do_not_depend_on_when_a_pose_is_held() {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = crate::device::seeded(1, || GestureNet::new(&vs.root(), GestureNetwork::FlatAndTurned, 30, 0, 32));
        let rest = crate::device::seeded(2, || Tensor::randn([1, 1, 30], (Kind::Float, Device::Cpu)));
        let pointing = crate::device::seeded(3, || Tensor::randn([1, 1, 30], (Kind::Float, Device::Cpu)));
        let frames = GESTURE_FRAMES as i64;
        let held = |from: i64| {
            let g = rest.expand([1, frames, 30], false).copy();
            g.narrow(1, from, 20).copy_(&pointing.expand([1, 20, 30], false));
            g
        };
        let (early, late) = tch::no_grad(|| (net.read(&held(10), None, None), net.read(&held(70), None, None)));
        assert_eq!(early.size(), [1, 32]);
        let per_frame = |t: &Tensor| t.narrow(1, 16, 16);
        assert!(per_frame(&early).allclose(&per_frame(&late), 1e-5, 1e-6, false), "{early} vs {late}");
        let still = tch::no_grad(|| net.read(&rest.expand([1, frames, 30], false), None, None));
        assert!(!per_frame(&early).allclose(&per_frame(&still), 1e-3, 1e-3, false), "the held pose must show");
        assert!(!early.narrow(1, 0, 16).allclose(&late.narrow(1, 0, 16), 1e-3, 1e-3, false), "flat: when");
    }

    /// Three distinct gestures of 5 values a frame (the last all zero: none shown), five rows
    /// showing them (`[0, 2, 1, 0, 2]`) and a pose per row.
    fn distinct_rows_and_poses() -> (Tensor, Tensor, Tensor) {
        let distinct =
            crate::device::seeded(2, || Tensor::randn([3, GESTURE_FRAMES as i64, 5], (Kind::Float, Device::Cpu)));
        let _ = distinct.get(2).zero_();
        let pose = crate::device::seeded(3, || Tensor::randn([5, 4], (Kind::Float, Device::Cpu)));
        (distinct, pose, Tensor::from_slice(&[0i64, 2, 1, 0, 2]))
    }

    /// `f`'s output and the gradients of its squared sum for every variable of `vs`.
    fn read_with_gradients(vs: &nn::VarStore, f: &dyn Fn() -> Tensor) -> (Tensor, Vec<Tensor>) {
        vs.trainable_variables().iter_mut().for_each(|v| v.zero_grad());
        let out = f();
        out.square().sum(Kind::Float).backward();
        (out.detach(), vs.trainable_variables().iter().map(|v| v.grad().copy()).collect())
    }

    /// The turned network reads rows through their distinct gestures as it reads them one by one
    /// (features and gradients), and what it reads of the pose: the flat half nothing, the
    /// per-frame half where the person stands and which way they face, for a shown gesture only.
    #[test]
    fn the_turned_network_joins_the_pose_after_the_frames() {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = crate::device::seeded(1, || GestureNet::new(&vs.root(), GestureNetwork::FlatAndTurned, 5, 4, 32));
        let (distinct, pose, rows) = distinct_rows_and_poses();
        let read = |f: &dyn Fn() -> Tensor| read_with_gradients(&vs, f);
        let g = distinct.index_select(0, &rows);
        let (want, want_grads) = read(&|| net.read(&g, None, Some(&pose)));
        let (got, grads) = read(&|| net.read(&distinct, Some(&rows), Some(&pose)));
        assert!(got.allclose(&want, 1e-5, 1e-6, false), "{got} vs {want}");
        // (summed in another order: float rounding of the gathered rows)
        for (a, b) in grads.iter().zip(&want_grads) {
            assert!(a.allclose(b, 1e-4, 1e-4, false), "gradients differ: {}", (a - b).abs().max());
        }
        // the same gestures with the person turned half round and moved
        let other =
            Tensor::stack(&[pose.select(1, 0) + 1.0, pose.select(1, 1), -pose.select(1, 2), -pose.select(1, 3)], 1);
        let moved = tch::no_grad(|| net.read(&g, None, Some(&other)));
        let (flat, turned) = (want.narrow(1, 0, 16), want.narrow(1, 16, 16));
        assert!(moved.narrow(1, 0, 16).equal(&flat), "the flat half reads the gesture alone");
        for r in 0..5 {
            let (a, b) = (turned.get(r), moved.narrow(1, 16, 16).get(r));
            let shown = r != 1 && r != 4;
            assert_eq!(!a.allclose(&b, 1e-4, 1e-4, false), shown, "row {r}: {a} vs {b}");
        }
        // without a pose, the pooled gesture alone
        let none = tch::no_grad(|| net.read(&g, None, None));
        assert!(!none.allclose(&want, 1e-3, 1e-3, false) && none.narrow(1, 0, 16).equal(&flat));
    }

    #[test]
    fn widths_and_variable_names() {
        let vs = nn::VarStore::new(Device::Cpu);
        let flat = GestureNet::new(&(vs.root() / "gesture"), GestureNetwork::Flat, 95, 0, 32);
        assert_eq!((flat.hidden(), flat.part_width(), flat.versions().len()), (32, 32, 2));
        let v = vs.variables();
        assert_eq!(v["gesture.weight"].size(), [32, 100 * 95], "§4.3.3's layer, as checkpoints name it");
        // turned: the per-frame half reads the gesture alone; B and C, then D, without biases
        let turned = GestureNet::new(&(vs.root() / "turned"), GestureNetwork::FlatAndTurned, 95, 4, 32);
        let v = vs.variables();
        assert_eq!(v["turned.flat.weight"].size(), [16, 100 * 95]);
        assert_eq!(v["turned.frame0.weight"].size(), [64, 95]);
        assert_eq!(v["turned.out.weight"].size(), [16, 128]);
        assert_eq!(v["turned.turn.weight"].size(), [32, 128]);
        assert_eq!(v["turned.place.weight"].size(), [16, 4]);
        assert!(!v.contains_key("turned.turn.bias") && !v.contains_key("turned.place.bias"));
        assert_eq!((turned.hidden(), turned.part_width()), (32, 16 + 3 * 16 + 1));
        assert_eq!(turned.versions().len(), 12, "a weight and a bias (or none) per layer");
        // without the pose: the per-frame half's features alone, no turn or place
        let alone = GestureNet::new(&(vs.root() / "alone"), GestureNetwork::FlatAndTurned, 95, 0, 32);
        assert_eq!((alone.part_width(), alone.versions().len()), (32, 8));
    }
}
