//! The PPO update of one full rollout (Algorithm 1's inner loop, §4.3.1), read top to bottom
//! as CleanRL's `ppo.py`: GAE on the host; then, for each epoch, for each minibatch of whole envs,
//! the network re-run over their sequences (the GRU from the stored initial memory), the
//! probability ratio, the clipped policy loss, the value loss, the entropy bonus, and an Adam
//! step with the gradient norm clipped.
//!
//! It changes only the network, the Adam and the minibatch order it is given, so the same code
//! learns in place or on a thread beside acting ([`super::overlap`]).

use farm::config::PpoConfig;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use tch::{Kind, Tensor};

use crate::logs::metrics::UpdateMetrics;
use crate::net::network::PolicyNet;
use crate::ppo::optim::Adam;
use crate::ppo::rollout::{Rollout, flags};
use crate::stages::{Stage, StageClock};

/// The linearly annealed learning rate after `frames` of the run's `total_frames` (§4.3.2: from
/// `ppo.lr` to 0).
pub fn lr_at(p: &PpoConfig, total_frames: u64, frames: u64) -> f64 {
    p.lr * (1.0 - frames as f64 / total_frames.max(1) as f64).max(0.0)
}

/// What an update reads besides the rollout and the state it changes.
#[derive(Clone, Debug)]
pub(crate) struct UpdateSettings {
    pub hp: PpoConfig,
    pub lr: f64,
    /// Asked before every minibatch: true ends the epochs there (a stop signal).
    pub interrupted: fn() -> bool,
}

/// The PPO update of a full rollout on `net`, whose trainable variables `opt` steps; `bootstrap`
/// is V(o_T) per env. The run's counters are the trainer's to fill.
pub(crate) fn update(
    net: &PolicyNet,
    opt: &mut Adam,
    rng: &mut ChaCha8Rng,
    r: &Rollout,
    bootstrap: &[f32],
    how: &UpdateSettings,
    stages: &StageClock,
) -> UpdateMetrics {
    let hp = &how.hp;
    opt.lr = how.lr;
    let mut m = UpdateMetrics { lr: how.lr, ..Default::default() };
    let valid_count = r.valid.iter().filter(|v| **v).count();
    m.valid_fraction = valid_count as f64 / (r.steps * r.envs) as f64;
    if net.spec().random() || valid_count == 0 {
        return m;
    }

    // GAE (Eq. 4.3–4.5), on the host: T×N scalars.
    let (advantages, returns) =
        gae(&r.rewards, &r.values, &r.ends, bootstrap, r.envs, hp.gamma as f32, hp.gae_lambda as f32);
    m.explained_variance = explained_variance(&r.values, &returns, &r.valid);
    let targets = Targets::of(r, &advantages, &returns);

    let mut means = Means::default();
    let mut envs: Vec<i64> = (0..r.envs as i64).collect();
    'epochs: for _epoch in 0..hp.epochs {
        envs.shuffle(rng);
        for mb in envs.chunks(r.envs.div_ceil(hp.minibatches)) {
            if (how.interrupted)() {
                m.cut_short = true;
                break 'epochs;
            }
            let losses = minibatch_losses(net, r, &targets, mb, hp, stages);
            opt.zero_grad();
            losses.total.backward();
            stages.lap(Stage::UpdateBackward);
            let grad_norm = opt.clip_grad_norm(hp.max_grad_norm);
            if !grad_norm.is_finite() {
                // one bad minibatch must not poison every weight with NaN
                m.skipped_steps += 1;
                continue;
            }
            opt.step();
            stages.lap(Stage::UpdateStep);
            means.add(&losses, grad_norm);
        }
    }
    means.write(&mut m);
    m
}

/// The rollout's per-step targets on its device, `[T, N]` each.
struct Targets {
    advantages: Tensor,
    returns: Tensor,
    log_probs: Tensor,
    values: Tensor,
    actions: Tensor,
    valid: Tensor,
}

impl Targets {
    fn of(r: &Rollout, advantages: &[f32], returns: &[f32]) -> Targets {
        Targets {
            advantages: r.to_device(advantages),
            returns: r.to_device(returns),
            log_probs: r.to_device(&r.log_probs),
            values: r.to_device(&r.values),
            actions: r.to_device(&r.actions),
            valid: flags(r, &r.valid),
        }
    }
}

/// One minibatch's loss, its parts, and how far the policy moved.
struct Losses {
    total: Tensor,
    policy: Tensor,
    value: Tensor,
    entropy: Tensor,
    approx_kl: f64,
    clip_fraction: f64,
}

/// The losses of the envs `mb`, their whole sequences re-run through the network.
fn minibatch_losses(
    net: &PolicyNet,
    r: &Rollout,
    t: &Targets,
    mb: &[i64],
    hp: &PpoConfig,
    stages: &StageClock,
) -> Losses {
    let idx = Tensor::from_slice(mb).to_device(r.device());
    let sel = |x: &Tensor| x.index_select(1, &idx);
    let starts: Vec<bool> =
        (0..r.steps).flat_map(|s| mb.iter().map(move |&k| r.starts[s * r.envs + k as usize])).collect();
    let valid = sel(&t.valid);
    let x = r.minibatch(&idx).expect("a full rollout has inputs");
    stages.lap(Stage::UpdatePrepare);

    let (logits, values) = net.evaluate(&x, &r.h0.index_select(1, &idx), &starts);
    let logp_all = logits.log_softmax(-1, Kind::Float);
    let new_logp = logp_all.gather(-1, &sel(&t.actions).unsqueeze(-1), false).squeeze_dim(-1);
    let entropy = -(logp_all.exp() * &logp_all).sum_dim_intlist(-1, false, Kind::Float);

    // Probability ratio r_t of Eq. 4.2, and how far the policy moved.
    let log_ratio = new_logp - sel(&t.log_probs);
    let ratio = log_ratio.exp();
    let (approx_kl, clip_fraction) = tch::no_grad(|| {
        let kl = masked_mean(&((&ratio - 1.0) - &log_ratio), &valid).double_value(&[]);
        let clipped = (&ratio - 1.0).abs().gt(hp.clip).to_kind(Kind::Float);
        (kl, masked_mean(&clipped, &valid).double_value(&[]))
    });

    // Advantages normalised over the minibatch's learnable steps.
    let adv = normalize_masked(&sel(&t.advantages), &valid);
    let policy = clipped_policy_loss(&ratio, &adv, &valid, hp.clip);
    let value = value_loss(&values, &sel(&t.values), &sel(&t.returns), &valid, hp.clip_value_loss.then_some(hp.clip));
    let entropy = masked_mean(&entropy, &valid);
    let total = &policy - hp.entropy_coef * &entropy + hp.value_coef * &value;
    Losses { total, policy, value, entropy, approx_kl, clip_fraction }
}

/// The update's metrics: means over the minibatches that stepped.
#[derive(Default)]
struct Means {
    sums: [f64; 6],
    batches: f64,
}

impl Means {
    fn add(&mut self, l: &Losses, grad_norm: f64) {
        let values = [
            l.policy.double_value(&[]),
            l.value.double_value(&[]),
            l.entropy.double_value(&[]),
            l.approx_kl,
            l.clip_fraction,
            grad_norm,
        ];
        for (s, v) in self.sums.iter_mut().zip(values) {
            *s += v;
        }
        self.batches += 1.0;
    }

    fn write(&self, m: &mut UpdateMetrics) {
        let [policy, value, entropy, kl, clip, grad] = self.sums.map(|s| s / self.batches.max(1.0));
        (m.policy_loss, m.value_loss, m.entropy) = (policy, value, entropy);
        (m.approx_kl, m.clip_fraction, m.grad_norm) = (kl, clip, grad);
    }
}

/// Generalised advantage estimation over `[T, N]` host arrays (index `t * N + n`):
/// δ_t = r_t + γ·V(s_{t+1})·(1 − end_t) − V(s_t),  A_t = δ_t + γλ·(1 − end_t)·A_{t+1}.
/// `bootstrap[n]` is V of the observation after the last step. Truncations already carry γ·V of
/// their final observation in `rewards`, and `ends` there, so one rule covers both endings.
/// Returns (advantages, returns = advantages + values).
pub fn gae(
    rewards: &[f32],
    values: &[f32],
    ends: &[bool],
    bootstrap: &[f32],
    envs: usize,
    gamma: f32,
    lambda: f32,
) -> (Vec<f32>, Vec<f32>) {
    let steps = rewards.len() / envs;
    let mut adv = vec![0.0f32; rewards.len()];
    for n in 0..envs {
        let mut last = 0.0f32;
        for t in (0..steps).rev() {
            let i = t * envs + n;
            let next_value = if t + 1 == steps { bootstrap[n] } else { values[i + envs] };
            let not_end = if ends[i] { 0.0 } else { 1.0 };
            let delta = rewards[i] + gamma * next_value * not_end - values[i];
            last = delta + gamma * lambda * not_end * last;
            adv[i] = last;
        }
    }
    let returns = adv.iter().zip(values).map(|(a, v)| a + v).collect();
    (adv, returns)
}

/// Mean of `x` over the entries where `valid` is 1.
pub fn masked_mean(x: &Tensor, valid: &Tensor) -> Tensor {
    (x * valid).sum(Kind::Float) / valid.sum(Kind::Float).clamp_min(1.0)
}

fn normalize_masked(x: &Tensor, valid: &Tensor) -> Tensor {
    let mean = masked_mean(x, valid);
    let std = masked_mean(&(x - &mean).square(), valid).sqrt();
    (x - mean) / (std + 1e-8)
}

/// The clipped surrogate of Eq. 4.2, as a loss to minimise:
/// mean over valid steps of max(−A·r, −A·clip(r, 1−ε, 1+ε)).
pub fn clipped_policy_loss(ratio: &Tensor, adv: &Tensor, valid: &Tensor, clip: f64) -> Tensor {
    let unclipped = -adv * ratio;
    let clipped = -adv * ratio.clamp(1.0 - clip, 1.0 + clip);
    masked_mean(&unclipped.maximum(&clipped), valid)
}

/// ½·mean (V − R)², or with `clip`, ½·mean max((V − R)², (V_old + clip(V − V_old, ±ε) − R)²).
pub fn value_loss(new: &Tensor, old: &Tensor, returns: &Tensor, valid: &Tensor, clip: Option<f64>) -> Tensor {
    let unclipped = (new - returns).square();
    let l = match clip {
        Some(c) => {
            let v_clipped = old + (new - old).clamp(-c, c);
            unclipped.maximum(&(v_clipped - returns).square())
        }
        None => unclipped,
    };
    0.5 * masked_mean(&l, valid)
}

/// 1 − Var(R − V) / Var(R) over valid steps (1: the critic explains the returns; ≤ 0: not at all).
pub fn explained_variance(values: &[f32], returns: &[f32], valid: &[bool]) -> f64 {
    let pairs: Vec<(f64, f64)> =
        values.iter().zip(returns).zip(valid).filter(|(_, v)| **v).map(|((v, r), _)| (*v as f64, *r as f64)).collect();
    if pairs.len() < 2 {
        return 0.0;
    }
    let var = |xs: &mut dyn Iterator<Item = f64>| {
        let v: Vec<f64> = xs.collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64
    };
    let var_r = var(&mut pairs.iter().map(|p| p.1));
    if var_r < 1e-12 {
        return 0.0;
    }
    1.0 - var(&mut pairs.iter().map(|p| p.1 - p.0)) / var_r
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(v: &[f32]) -> Tensor {
        Tensor::from_slice(v)
    }

    /// γ = λ = 0.5, one env, V = [1, 2, 3, 4], r = 1 everywhere, the episode ends after step 1,
    /// V(next) = 8:
    /// t3: δ = 1 + .5·8 − 4 = 1                       A = 1
    /// t2: δ = 1 + .5·4 − 3 = 0                       A = 0 + .25·1 = 0.25
    /// t1: ended: δ = 1 − 2 = −1                      A = −1
    /// t0: δ = 1 + .5·2 − 1 = 1                       A = 1 + .25·(−1) = 0.75
    #[test]
    fn gae_by_hand_with_an_episode_end() {
        let (a, r) = gae(&[1.0; 4], &[1.0, 2.0, 3.0, 4.0], &[false, true, false, false], &[8.0], 1, 0.5, 0.5);
        assert_eq!(a, vec![0.75, -1.0, 0.25, 1.0]);
        assert_eq!(r, vec![1.75, 1.0, 3.25, 5.0]);
    }

    /// The rollout's view of a truncation (γ·V(final obs) folded into the reward, `ends` set)
    /// through GAE, with two envs interleaved: env 0 is truncated after step 0 with V(final) = 6,
    /// env 1 terminates after step 0 (no bootstrap).
    #[test]
    fn gae_truncated_bootstraps_terminated_does_not() {
        let gamma = 0.5;
        // env 0: r0 = 0.5 + γ·6 = 3.5 (truncation), step 1 is the ignored final observation.
        let rewards = [0.5 + gamma * 6.0, 1.0, 0.0, 0.0];
        let values = [2.0, 2.0, 6.0, 0.5];
        let ends = [true, true, true, false];
        let (a, _) = gae(&rewards, &values, &ends, &[9.0, 4.0], 2, gamma, 1.0);
        // env 0 t0: δ = 3.5 − 2 = 1.5 (= r + γ·V(final) − V), nothing flows back from t1
        assert_eq!(a[0], 1.5);
        // env 1 t0: terminated: δ = 1 − 2 = −1, V(s1) ignored
        assert_eq!(a[1], -1.0);
        // env 1 t1: δ = 0 + .5·4 − .5 = 1.5
        assert_eq!(a[3], 1.5);
    }

    /// ratio [0.5, 1, 1.5, 1.5], A [1, −1, 1, −1], ε = 0.2:
    /// max(−A·r, −A·clip(r)) = [max(−.5, −.8), max(1, 1), max(−1.5, −1.2), max(1.5, 1.2)]
    ///                       = [−0.5, 1, −1.2, 1.5] → mean 0.2; without the last step −0.7/3.
    #[test]
    fn clipped_loss_by_hand() {
        let ratio = t(&[0.5, 1.0, 1.5, 1.5]);
        let adv = t(&[1.0, -1.0, 1.0, -1.0]);
        let all = t(&[1.0; 4]);
        let l = clipped_policy_loss(&ratio, &adv, &all, 0.2).double_value(&[]);
        assert!((l - 0.2).abs() < 1e-6, "{l}");
        let l = clipped_policy_loss(&ratio, &adv, &t(&[1.0, 1.0, 1.0, 0.0]), 0.2).double_value(&[]);
        assert!((l + 0.7 / 3.0).abs() < 1e-6, "{l}");
    }

    /// old V [0, 0], new V [1, −0.1], R [2, 1], ε = 0.2:
    /// (1−2)² = 1 vs clipped (0.2−2)² = 3.24 → 3.24; (−0.1−1)² = 1.21 (inside the clip)
    /// → ½·(3.24 + 1.21)/2 = 1.1125; unclipped: ½·(1 + 1.21)/2 = 0.5525.
    #[test]
    fn value_loss_by_hand() {
        let (new, old, ret, all) = (t(&[1.0, -0.1]), t(&[0.0, 0.0]), t(&[2.0, 1.0]), t(&[1.0, 1.0]));
        let l = value_loss(&new, &old, &ret, &all, Some(0.2)).double_value(&[]);
        assert!((l - 1.1125).abs() < 1e-6, "{l}");
        let l = value_loss(&new, &old, &ret, &all, None).double_value(&[]);
        assert!((l - 0.5525).abs() < 1e-6, "{l}");
    }

    #[test]
    fn explained_variance_extremes() {
        let r = [1.0, 2.0, 3.0];
        assert!((explained_variance(&r, &r, &[true; 3]) - 1.0).abs() < 1e-9);
        assert!(explained_variance(&[0.0; 3], &r, &[true; 3]).abs() < 1e-9);
    }

    #[test]
    fn lr_decays_linearly_to_zero() {
        let cfg =
            farm::config::RunConfig::from_toml("[run]\nmethod = \"both\"\ntotal_frames = 1000\n", "x.toml").unwrap();
        let lr = |frames| lr_at(&cfg.ppo, cfg.run.total_frames, frames);
        assert_eq!(lr(0), 3e-4);
        assert!((lr(250) - 2.25e-4).abs() < 1e-12);
        assert_eq!(lr(1000), 0.0);
        assert_eq!(lr(5000), 0.0);
    }
}
