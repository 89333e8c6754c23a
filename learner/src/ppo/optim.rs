//! Adam (§4.3.2) with its state in plain tensors, so checkpoints can carry it: libtorch's
//! optimizer behind tch keeps `exp_avg`, `exp_avg_sq` and `step` out of reach.
//! Same update as `torch.optim.Adam` (no weight decay, no amsgrad).

use tch::{Kind, Tensor, nn};

#[derive(Debug)]
pub struct Adam {
    /// Learning rate of the next step (the PPO loop anneals it).
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    /// Steps taken (bias correction), as `state["step"]` in torch.
    pub step: i64,
    /// Trainable variables, sorted by name (a stable order for checkpoints).
    params: Vec<(String, Tensor)>,
    exp_avg: Vec<Tensor>,
    exp_avg_sq: Vec<Tensor>,
}

impl Adam {
    /// Adam over the variables of `vs` that require gradients (frozen ones are left out).
    pub fn new(vs: &nn::VarStore, lr: f64, eps: f64) -> Adam {
        let mut params: Vec<(String, Tensor)> = vs.variables().into_iter().filter(|(_, t)| t.requires_grad()).collect();
        params.sort_by(|a, b| a.0.cmp(&b.0));
        let exp_avg = params.iter().map(|(_, p)| p.zeros_like()).collect();
        let exp_avg_sq = params.iter().map(|(_, p)| p.zeros_like()).collect();
        Adam { lr, beta1: 0.9, beta2: 0.999, eps, step: 0, params, exp_avg, exp_avg_sq }
    }

    pub fn zero_grad(&mut self) {
        for (_, p) in &mut self.params {
            p.zero_grad();
        }
    }

    /// Scales gradients so their global L2 norm is at most `max`; returns the norm before.
    pub fn clip_grad_norm(&mut self, max: f64) -> f64 {
        tch::no_grad(|| {
            let grads: Vec<Tensor> = self.params.iter().map(|(_, p)| p.grad()).filter(|g| g.defined()).collect();
            if grads.is_empty() {
                return 0.0;
            }
            let sq: Vec<Tensor> = grads.iter().map(|g| g.to_kind(Kind::Float).square().sum(Kind::Float)).collect();
            let total = Tensor::stack(&sq, 0).sum(Kind::Float).sqrt().double_value(&[]);
            let scale = max / (total + 1e-6);
            if scale < 1.0 {
                for mut g in grads {
                    let _ = g.g_mul_scalar_(scale);
                }
            }
            total
        })
    }

    /// One Adam step with the current `lr`.
    pub fn step(&mut self) {
        self.step += 1;
        let (b1, b2) = (self.beta1, self.beta2);
        let bias1 = 1.0 - b1.powi(self.step as i32);
        let bias2_sqrt = (1.0 - b2.powi(self.step as i32)).sqrt();
        let step_size = self.lr / bias1;
        tch::no_grad(|| {
            for (i, (_, p)) in self.params.iter_mut().enumerate() {
                let g = p.grad();
                if !g.defined() {
                    continue;
                }
                let m = &mut self.exp_avg[i];
                let v = &mut self.exp_avg_sq[i];
                let _ = m.lerp_(&g, 1.0 - b1);
                let _ = v.g_mul_scalar_(b2);
                let _ = v.g_add_(&(&g * &g * (1.0 - b2)));
                let denom = v.sqrt() / bias2_sqrt + self.eps;
                let _ = p.g_sub_(&(&*m / denom * step_size));
            }
        });
    }

    /// Makes this optimizer and the variables it steps those of `other`, built for the same
    /// network in another VarStore: weights, moments, step and lr, so either goes on where the
    /// other stopped.
    pub fn copy_from(&mut self, other: &Adam) {
        assert!(
            self.params.iter().map(|p| &p.0).eq(other.params.iter().map(|p| &p.0)),
            "Adam::copy_from: another network's variables"
        );
        tch::no_grad(|| {
            for (i, (_, p)) in self.params.iter_mut().enumerate() {
                p.copy_(&other.params[i].1);
                self.exp_avg[i].copy_(&other.exp_avg[i]);
                self.exp_avg_sq[i].copy_(&other.exp_avg_sq[i]);
            }
        });
        (self.step, self.lr) = (other.step, other.lr);
    }

    /// Named state tensors: `exp_avg.<var>` and `exp_avg_sq.<var>`.
    pub fn state(&self) -> Vec<(String, Tensor)> {
        let mut out = Vec::with_capacity(2 * self.params.len());
        for (i, (name, _)) in self.params.iter().enumerate() {
            out.push((format!("exp_avg.{name}"), self.exp_avg[i].shallow_clone()));
            out.push((format!("exp_avg_sq.{name}"), self.exp_avg_sq[i].shallow_clone()));
        }
        out
    }

    /// The state tensor a checkpoint must provide for `name` (as given by [`Adam::state`]).
    pub fn state_mut(&mut self, name: &str) -> Option<&mut Tensor> {
        let (kind, var) = name.split_once('.')?;
        let i = self.params.iter().position(|(n, _)| n == var)?;
        match kind {
            "exp_avg" => Some(&mut self.exp_avg[i]),
            "exp_avg_sq" => Some(&mut self.exp_avg_sq[i]),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    /// Two steps on f(w) = Σ w², against Adam's formulas by hand.
    #[test]
    fn matches_torch_adam_by_hand() {
        let vs = nn::VarStore::new(Device::Cpu);
        let w = vs.root().var("w", &[2], nn::Init::Const(1.0));
        let mut opt = Adam::new(&vs, 0.1, 1e-8);
        for _ in 0..2 {
            opt.zero_grad();
            (&w * &w).sum(Kind::Float).backward();
            opt.step();
        }
        // step 1: g = 2, m = 0.2, v = 0.004; m̂ = 2, v̂ = 4; w = 1 - 0.1 * 2/2 = 0.9
        // step 2: g = 1.8, m = 0.36, v = 0.007236; m̂ = 1.8947, v̂ = 3.6190; w = 0.9 - 0.1*0.99596
        let m2: f64 = 0.9 * 0.2 + 0.1 * 1.8;
        let v2: f64 = 0.999 * 0.004 + 0.001 * 1.8 * 1.8;
        let mh = m2 / (1.0 - 0.81);
        let vh = v2 / (1.0 - 0.999f64.powi(2));
        let want = 0.9 - 0.1 * mh / (vh.sqrt() + 1e-8);
        assert!((w.double_value(&[0]) - want).abs() < 1e-6, "{} vs {want}", w.double_value(&[0]));
        assert_eq!(opt.step, 2);
        assert_eq!(opt.state().len(), 2);
    }

    #[test]
    fn clipping_bounds_the_global_norm() {
        let vs = nn::VarStore::new(Device::Cpu);
        let w = vs.root().var("w", &[4], nn::Init::Const(3.0));
        let mut opt = Adam::new(&vs, 0.1, 1e-8);
        (&w * &w).sum(Kind::Float).backward(); // grad 6 each, norm 12
        let before = opt.clip_grad_norm(0.5);
        assert!((before - 12.0).abs() < 1e-4);
        let after = w.grad().square().sum(Kind::Float).sqrt().double_value(&[]);
        assert!((after - 0.5).abs() < 1e-4);
    }
}
