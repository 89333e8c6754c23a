//! The GRU over a minibatch's whole sequences as one call ([`gru_over_stretches`]).
//!
//! PPO re-runs the GRU over T steps × B envs, each env's memory reset where one of its episodes
//! starts. A fused GRU cannot reset part of its batch mid-sequence; cutting the whole batch at
//! every step where *any* env starts an episode would make, with 128 envs in a minibatch, nearly
//! one call per step. So each env's steps are cut at its own starts into stretches, and the
//! stretches run side by side as torch's packed sequences (longest first): one call, as long as
//! the longest stretch, whatever the number of episodes.

use tch::{Device, Tensor, nn};

/// Each env's steps cut at its episode starts, laid out as torch's packed sequences.
#[derive(Debug, PartialEq)]
pub(crate) struct Stretches {
    /// For each packed row (step by step, the stretches still running at that step, longest
    /// first), the input row `t * B + b` it reads.
    pub rows: Vec<i64>,
    /// Stretches still running at each step: torch's `batch_sizes`.
    pub batch_sizes: Vec<i64>,
    /// Per stretch (packed order), the env whose initial memory it continues, or B for a zero
    /// memory (it begins with an episode start).
    pub first_memory: Vec<i64>,
    /// Per env, the packed index of its last stretch (whose final memory is the env's).
    pub last: Vec<i64>,
}

impl Stretches {
    /// `starts[t * envs + b]`: env b's observation t starts an episode.
    pub(crate) fn of(starts: &[bool], steps: usize, envs: usize) -> Stretches {
        assert_eq!(starts.len(), steps * envs, "starts must be T × B");
        // (length, env, first step), one per stretch
        let mut spans = Vec::new();
        for b in 0..envs {
            let mut t0 = 0;
            for t in 1..=steps {
                if t == steps || starts[t * envs + b] {
                    spans.push((t - t0, b, t0));
                    t0 = t;
                }
            }
        }
        // longest first; ties in env then time order, so the layout is a function of `starts`
        spans.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        let longest = spans.first().map_or(0, |s| s.0);
        let batch_sizes: Vec<i64> =
            (0..longest).map(|s| spans.iter().take_while(|span| span.0 > s).count() as i64).collect();
        let mut rows = Vec::with_capacity(steps * envs);
        for (s, &running) in batch_sizes.iter().enumerate() {
            rows.extend(spans[..running as usize].iter().map(|&(_, b, t0)| ((t0 + s) * envs + b) as i64));
        }
        let first_memory =
            spans.iter().map(|&(_, b, t0)| if t0 == 0 && !starts[b] { b as i64 } else { envs as i64 }).collect();
        let mut last = vec![0i64; envs];
        let mut last_t0 = vec![None; envs];
        for (i, &(_, b, t0)) in spans.iter().enumerate() {
            if last_t0[b].is_none_or(|t| t0 > t) {
                last_t0[b] = Some(t0);
                last[b] = i as i64;
            }
        }
        Stretches { rows, batch_sizes, first_memory, last }
    }

    /// For each input row `t * B + b`, its packed row (the inverse of `rows`).
    pub(crate) fn unpack(&self) -> Vec<i64> {
        let mut inverse = vec![0i64; self.rows.len()];
        for (packed, &row) in self.rows.iter().enumerate() {
            inverse[row as usize] = packed as i64;
        }
        inverse
    }
}

/// The GRU (its `weights` in torch's flat order: per layer w_ih, w_hh, b_ih, b_hh) over `x`
/// `[T, B, D]` from `h0` `[L, B, H]`, env b's memory reset where `starts[t * B + b]`. Returns the
/// outputs `[T, B, H]` and each env's final memory `[L, B, H]`.
pub(crate) fn gru_over_stretches(
    weights: &[Tensor],
    layers: i64,
    x: &Tensor,
    h0: &Tensor,
    starts: &[bool],
) -> (Tensor, Tensor) {
    let (steps, envs) = (x.size()[0], x.size()[1]);
    let s = Stretches::of(starts, steps as usize, envs as usize);
    let device = x.device();
    let on = |v: &[i64]| Tensor::from_slice(v).to_device(device);
    let data = x.flatten(0, 1).index_select(0, &on(&s.rows));
    // h0 with a zero memory appended at index B, for the stretches that begin an episode
    let zero = h0.zeros_like().narrow(1, 0, 1);
    let hx = Tensor::cat(&[h0, &zero], 1).index_select(1, &on(&s.first_memory));
    // batch_sizes stay on the host, as torch's packed sequences want them
    let batch_sizes = Tensor::from_slice(&s.batch_sizes).to_device(Device::Cpu);
    let (out, h_n) = Tensor::gru_data(&data, &batch_sizes, &hx, weights, true, layers, 0.0, true, false);
    let out = out.index_select(0, &on(&s.unpack())).view([steps, envs, -1]);
    (out, h_n.index_select(1, &on(&s.last)))
}

/// The GRU's variables under `path` (as `nn::gru` named them) in torch's flat order.
pub(crate) fn flat_weights(vs: &nn::VarStore, path: &str, layers: i64) -> Vec<Tensor> {
    let vars = vs.variables();
    (0..layers)
        .flat_map(|l| ["weight_ih", "weight_hh", "bias_ih", "bias_hh"].map(|w| format!("{path}.{w}_l{l}")))
        .map(|name| vars.get(&name).unwrap_or_else(|| panic!("GRU variable {name}")).shallow_clone())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Kind;
    use tch::nn::RNN;

    /// Two envs over four steps: env 0 starts an episode at 0 and 2, env 1 at 3.
    #[test]
    fn stretches_are_packed_longest_first() {
        #[rustfmt::skip]
        let starts = [
            true, false,
            false, false,
            true, false,
            false, true,
        ];
        let s = Stretches::of(&starts, 4, 2);
        // stretches: env 1 steps 0–2 (3, from h0), env 0 steps 0–1 (2, zero), env 0 steps 2–3 (2, zero), env 1 step 3 (1, zero)
        assert_eq!(s.batch_sizes, [4, 3, 1]);
        assert_eq!(s.rows, [1, 0, 4, 7, 3, 2, 6, 5]);
        assert_eq!(s.first_memory, [1, 2, 2, 2]);
        assert_eq!(s.last, [2, 3]);
        let u = s.unpack();
        assert!(u.iter().enumerate().all(|(row, &p)| s.rows[p as usize] == row as i64));
    }

    /// The packed call gives what the GRU gives env by env, step by step, with the memory zeroed
    /// at each start — outputs, final memories and gradients.
    #[test]
    fn one_packed_call_equals_stepping_each_env() {
        let vs = nn::VarStore::new(Device::Cpu);
        let cfg = nn::RNNConfig { num_layers: 2, batch_first: false, ..Default::default() };
        let gru = crate::device::seeded(5, || nn::gru(vs.root() / "gru", 3, 4, cfg));
        let weights = flat_weights(&vs, "gru", 2);
        let (t_len, b) = (6usize, 3usize);
        let (x, h0) = crate::device::seeded(6, || {
            (
                Tensor::randn([t_len as i64, b as i64, 3], (Kind::Float, Device::Cpu)),
                Tensor::randn([2, b as i64, 4], (Kind::Float, Device::Cpu)),
            )
        });
        let starts: Vec<bool> = (0..t_len * b).map(|i| [0, 4, 7, 11, 14].contains(&i)).collect();
        let (out, h_last) = gru_over_stretches(&weights, 2, &x, &h0, &starts);
        for env in 0..b {
            let mut h = h0.narrow(1, env as i64, 1);
            for t in 0..t_len {
                if starts[t * b + env] {
                    h = h.zeros_like();
                }
                let (o, s) = gru.seq_init(&x.narrow(0, t as i64, 1).narrow(1, env as i64, 1), &nn::GRUState(h));
                h = s.0;
                let got = out.get(t as i64).get(env as i64);
                assert!(got.allclose(&o.view([-1]), 1e-5, 1e-6, false), "t {t} env {env}");
            }
            assert!(h_last.narrow(1, env as i64, 1).allclose(&h, 1e-5, 1e-6, false), "final memory of env {env}");
        }
        (out.sum(Kind::Float) + h_last.sum(Kind::Float)).backward();
        assert!(weights.iter().all(|w| w.grad().defined() && w.grad().abs().sum(Kind::Float).double_value(&[]) > 0.0));
    }
}
