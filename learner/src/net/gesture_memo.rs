//! Acting's gesture parts, kept per env from one step to the next.
//!
//! An env shows the same 100 × 95 gesture from an episode's start until intervention switches
//! on or off, yet acting would run the gesture network (9,500 wide) over all N envs at every step,
//! a large share of a step's forward at 64×64 on a CPU. The memo keeps each env's part
//! ([`GestureNet::part`]: what the network reads of the gesture alone, the features themselves
//! unless the pose joins after) and the gesture it came from, and recomputes only the envs whose
//! gesture changed (compared element by element) or all of them when the network's weights
//! changed: PPO's Adam and checkpoint loading write the variables in place, which bumps torch's
//! version counters of its weights and biases (libtorch's own optimizers write through `.data()`
//! and would not: the tests use ours).

use tch::{Kind, Tensor};

use crate::net::gesture_net::GestureNet;

#[derive(Debug, Default)]
pub(crate) struct GestureMemo {
    /// `[N, 100, 95]`: what each env showed when its part was computed.
    shown: Option<Tensor>,
    /// `[N, part_width]`.
    parts: Option<Tensor>,
    /// Rows computed with the current network (a round of one group of envs leaves the other
    /// rows as they were).
    fresh: Vec<bool>,
    /// The network's version counters the fresh rows were computed with.
    versions: Vec<i64>,
}

impl GestureMemo {
    /// The network's parts of `g` `[B, 100, 95]` — the gestures of envs `at..at + B` of `total` —
    /// `[B, part_width]`, reusing every row whose gesture and network are unchanged since it was
    /// last computed. Without gradients (acting only); [`GestureNet::join`] makes features of them.
    pub(crate) fn parts(&mut self, net: &GestureNet, g: &Tensor, at: usize, total: usize) -> Tensor {
        tch::no_grad(|| {
            let versions = net.versions();
            let mut all = g.size();
            all[0] = total as i64;
            if !self.shown.as_ref().is_some_and(|s| s.size() == all && s.kind() == g.kind()) {
                self.shown = Some(g.new_zeros(all.as_slice(), (g.kind(), g.device())));
                self.parts = Some(Tensor::zeros([total as i64, net.part_width()], (Kind::Float, g.device())));
                self.fresh = vec![false; total];
            }
            if versions != self.versions {
                self.fresh.iter_mut().for_each(|f| *f = false);
                self.versions = versions;
            }
            let (at, n) = (at as i64, g.size()[0]);
            let mut shown = self.shown.as_ref().unwrap().narrow(0, at, n);
            let mut parts = self.parts.as_ref().unwrap().narrow(0, at, n);
            let fresh = &mut self.fresh[at as usize..(at + n) as usize];
            let same = g.eq_tensor(&shown).flatten(1, -1).all_dim(1, false).to_device(tch::Device::Cpu);
            let same = Vec::<bool>::try_from(same).expect("a bool per env");
            let changed: Vec<i64> = (0..n).filter(|&k| !(same[k as usize] && fresh[k as usize])).collect();
            if !changed.is_empty() {
                let rows = Tensor::from_slice(&changed).to_device(g.device());
                let new = g.index_select(0, &rows);
                let _ = parts.index_copy_(0, &rows, &net.part(&new));
                let _ = shown.index_copy_(0, &rows, &new);
                changed.iter().for_each(|&k| fresh[k as usize] = true);
            }
            // the memo's own storage is updated in place next step: hand out a copy
            parts.copy()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farm::config::GestureNetwork;
    use tch::{Device, nn};

    /// Every kind of gesture network acting keeps parts of, on gestures of 5 values per frame,
    /// 8 wide (the one that turns by the pose reads it).
    fn nets(vs: &nn::VarStore) -> Vec<(String, GestureNet)> {
        [GestureNetwork::Flat, GestureNetwork::FlatAndTurned]
            .into_iter()
            .enumerate()
            .map(|(i, k)| {
                let pose_dims = if k == GestureNetwork::FlatAndTurned { 4 } else { 0 };
                (format!("g{i}."), GestureNet::new(&(vs.root() / format!("g{i}")), k, 5, pose_dims, 8))
            })
            .collect()
    }

    /// The person's pose of 4 envs, for the network that reads it after the memo.
    fn pose(net: &GestureNet) -> Option<Tensor> {
        matches!(net, GestureNet::FlatAndTurned(..))
            .then(|| crate::device::seeded(11, || Tensor::randn([4, 4], (Kind::Float, Device::Cpu))))
    }

    fn draw(seed: i64, n: i64) -> Tensor {
        let frames = shm_schema::GESTURE_FRAMES as i64;
        crate::device::seeded(seed, || Tensor::randn([n, frames, 5], (Kind::Float, Device::Cpu)).to_kind(Kind::Half))
    }

    /// A checkpoint load: one of the network's variables (the first by name) overwritten in place,
    /// without gradients.
    fn load_over(vs: &nn::VarStore, prefix: &str, seed: i64) {
        let vars = vs.variables();
        let name = vars.keys().filter(|k| k.starts_with(prefix)).min().expect("a variable");
        let v = &vars[name];
        let other = crate::device::seeded(seed, || v.randn_like());
        tch::no_grad(|| v.shallow_clone().copy_(&other));
    }

    /// Features from the memo's parts equal the network run on every row: when some envs change gesture,
    /// when none does, and after the weights change in place.
    #[test]
    fn memo_equals_recomputing_every_row() {
        let vs = nn::VarStore::new(Device::Cpu);
        let nets = crate::device::seeded(3, || nets(&vs));
        for (prefix, net) in &nets {
            let mut memo = GestureMemo::default();
            let mut g = draw(4, 4);
            let pose = pose(net);
            let check = |memo: &mut GestureMemo, g: &Tensor| {
                let got = net.join(&memo.parts(net, g, 0, 4), pose.as_ref());
                let want = tch::no_grad(|| net.read(g, None, pose.as_ref()));
                assert!(got.allclose(&want, 1e-5, 1e-6, false), "{prefix}: {got} vs {want}");
            };
            check(&mut memo, &g);
            check(&mut memo, &g);
            // envs 1 and 3 start new episodes with other gestures
            let fresh = draw(5, 2);
            let _ = g.index_copy_(0, &Tensor::from_slice(&[1i64, 3]), &fresh);
            check(&mut memo, &g);
            // PPO's optimizer step changes the network in place
            let mut opt = crate::ppo::optim::Adam::new(&vs, 0.5, 1e-5);
            net.read(&g, None, pose.as_ref()).sum(Kind::Float).backward();
            opt.step();
            check(&mut memo, &g);
            // so does a checkpoint load
            load_over(&vs, prefix, 6);
            check(&mut memo, &g);
        }
    }

    /// Rounds of one group of envs at a time (`ppo.env_groups`): each group's rows are its own,
    /// and a change of the network reaches every group that acts after it.
    #[test]
    fn groups_of_envs_keep_their_own_rows() {
        let vs = nn::VarStore::new(Device::Cpu);
        let nets = crate::device::seeded(8, || nets(&vs));
        let g = draw(9, 4);
        for (prefix, net) in &nets {
            let mut memo = GestureMemo::default();
            let pose = pose(net);
            let mut check = |at: i64| {
                let part = g.narrow(0, at, 2);
                let pose = pose.as_ref().map(|p| p.narrow(0, at, 2));
                let got = net.join(&memo.parts(net, &part, at as usize, 4), pose.as_ref());
                let want = tch::no_grad(|| net.read(&part, None, pose.as_ref()));
                assert!(got.allclose(&want, 1e-5, 1e-6, false), "{prefix} envs {at}..: {got} vs {want}");
            };
            for at in [0, 2, 0, 2] {
                check(at);
            }
            load_over(&vs, prefix, 10);
            check(2);
            check(0);
        }
    }

    /// A handed-out tensor is not changed by later calls.
    #[test]
    fn handed_out_features_stay_as_they_were() {
        let vs = nn::VarStore::new(Device::Cpu);
        let nets = crate::device::seeded(7, || nets(&vs));
        let (_, net) = &nets[0];
        let mut memo = GestureMemo::default();
        let a = draw(1, 2).zeros_like();
        let first = memo.parts(net, &a, 0, 2);
        let kept = first.copy();
        let _ = memo.parts(net, &a.ones_like(), 0, 2);
        assert!(first.equal(&kept));
    }
}
