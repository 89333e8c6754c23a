//! The rollout's gestures, each distinct one stored once.
//!
//! An env's gesture changes only when an episode starts and when intervention switches on or
//! off; between those it is the same 100 × 95 motion at every step. The table compares each
//! env's new gesture with the one it showed at the previous step (exactly, element by element):
//! the same one keeps its row, a new one gets a row. PPO then encodes, per minibatch, the rows its
//! envs showed and gathers (`Inputs::gesture_index`), instead of running the 9,500-wide gesture
//! layer over every stored step.

use tch::{Device, Kind, Tensor};

#[derive(Debug)]
pub struct GestureTable {
    /// Distinct gestures, `[capacity, 100, 95]`; the first `len` rows are in use.
    rows: Tensor,
    len: i64,
    /// Row of each stored step, `[T, N]` i64 (on the device).
    ids: Tensor,
    /// Row each env showed at the previous step (-1: none yet in this rollout).
    last: Vec<i64>,
}

impl GestureTable {
    /// Room for `steps` × `envs` gestures shaped like `one` (`[100, 95]`, its kind and device).
    pub fn new(steps: usize, envs: usize, one: &Tensor) -> GestureTable {
        let mut shape = vec![(steps * envs) as i64];
        shape.extend(one.size());
        GestureTable {
            rows: Tensor::zeros(shape.as_slice(), (one.kind(), one.device())),
            len: 0,
            ids: Tensor::zeros([steps as i64, envs as i64], (Kind::Int64, one.device())),
            last: vec![-1; envs],
        }
    }

    /// Forgets every gesture (a new rollout); the storage is reused.
    pub fn clear(&mut self) {
        self.len = 0;
        self.last.iter_mut().for_each(|r| *r = -1);
    }

    /// Distinct gestures stored so far.
    pub fn len(&self) -> usize {
        self.len as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Stores step `t`'s gestures `[N, 100, 95]`.
    pub fn push(&mut self, t: usize, g: &Tensor) {
        self.push_at(t, 0, g)
    }

    /// Stores step `t`'s gestures of envs `at..at + B`, `g` `[B, 100, 95]` (one group of an
    /// acting round).
    pub fn push_at(&mut self, t: usize, at: usize, g: &Tensor) {
        let n = g.size()[0] as usize;
        let last = &mut self.last[at..at + n];
        tch::no_grad(|| {
            // each env's gesture at the previous step (-1: none yet in this rollout)
            let known: Vec<bool> = last.iter().map(|&r| r >= 0).collect();
            let same: Vec<bool> = if known.iter().any(|&k| k) {
                let ids: Vec<i64> = last.iter().map(|&r| r.max(0)).collect();
                let prev = self.rows.index_select(0, &Tensor::from_slice(&ids).to_device(self.rows.device()));
                let eq = g.eq_tensor(&prev).flatten(1, -1).all_dim(1, false);
                let eq = Vec::<bool>::try_from(eq.to_device(Device::Cpu)).expect("a bool per env");
                eq.iter().zip(&known).map(|(e, k)| *e && *k).collect()
            } else {
                vec![false; n]
            };
            let fresh: Vec<i64> = (0..n as i64).filter(|&k| !same[k as usize]).collect();
            if !fresh.is_empty() {
                let src = g.index_select(0, &Tensor::from_slice(&fresh).to_device(g.device()));
                self.rows.narrow(0, self.len, fresh.len() as i64).copy_(&src);
            }
            let mut next = self.len;
            for (k, s) in same.iter().enumerate() {
                if !s {
                    last[k] = next;
                    next += 1;
                }
            }
            self.len = next;
            self.ids.get(t as i64).narrow(0, at as i64, n as i64).copy_(&Tensor::from_slice(last));
        });
    }

    /// The distinct gestures in use, `[G, 100, 95]`.
    pub fn rows(&self) -> Tensor {
        self.rows.narrow(0, 0, self.len)
    }

    /// Row of every stored step, `[T, N]`.
    pub fn ids(&self) -> &Tensor {
        &self.ids
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gesture(v: f64) -> Tensor {
        Tensor::full([1, 4, 3], v, (Kind::Half, Device::Cpu))
    }

    #[test]
    fn a_repeated_gesture_keeps_its_row_and_a_change_gets_a_new_one() {
        let mut t = GestureTable::new(3, 2, &gesture(0.0).squeeze_dim(0));
        // env 0 shows a, then a again, then b; env 1 shows zeros, then c, then c
        let steps = [[1.0, 0.0], [1.0, 2.0], [3.0, 2.0]];
        for (i, s) in steps.iter().enumerate() {
            t.push(i, &Tensor::cat(&[gesture(s[0]), gesture(s[1])], 0));
        }
        assert_eq!(t.len(), 4); // a, zeros, c, b
        let ids = Vec::<i64>::try_from(t.ids().flatten(0, -1)).unwrap();
        assert_eq!(ids, vec![0, 1, 0, 2, 3, 2]);
        // every step's gesture is its row of the table
        let rows = t.rows().index_select(0, &t.ids().flatten(0, -1));
        let want: Vec<f32> = steps.iter().flatten().map(|&v| v as f32).collect();
        let got = Vec::<f32>::try_from(rows.to_kind(Kind::Float).mean_dim(&[1i64, 2][..], false, Kind::Float)).unwrap();
        assert_eq!(got, want);
        t.clear();
        t.push(0, &Tensor::cat(&[gesture(1.0), gesture(1.0)], 0));
        assert_eq!(t.len(), 2, "a new rollout compares nothing with the old one");
    }
}
