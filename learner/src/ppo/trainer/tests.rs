use tch::Tensor;

use super::*;

/// A stop during an update ends its epochs before the next minibatch: nothing more is
/// learned from the rollout, the update is counted (its frames were collected) and says so.
#[test]
fn a_stop_cuts_the_update_short() {
    let mut cfg = crate::bench::tiny_config();
    cfg.ppo.rollout = 8;
    let mut t = Trainer::new(&cfg, 2, Device::Cpu).unwrap();
    crate::bench::fill_rollout(&mut t, 1).unwrap();
    let before: Vec<Tensor> = t.agent.vs.trainable_variables().iter().map(|v| v.copy()).collect();
    t.interrupted = || true;
    let m = crate::bench::update_once(&mut t);
    assert!(m.cut_short && m.update == 1 && m.frames == 16, "{m:?}");
    let after = t.agent.vs.trainable_variables();
    assert!(before.iter().zip(&after).all(|(a, b)| a.equal(b)), "weights moved");
    crate::bench::fill_rollout(&mut t, 2).unwrap();
    t.interrupted = || false;
    let m = crate::bench::update_once(&mut t);
    assert!(!m.cut_short && m.update == 2);
    assert!(before.iter().zip(&t.agent.vs.trainable_variables()).any(|(a, b)| !a.equal(b)), "learned");
}

/// Env groups change when envs are inferred, not what they do or learn: a trainer acting on
/// two halves of its envs in turn (each rollout's last step on all) takes the actions, stores
/// the rollout and makes the updates of one acting on all at once — over two rollouts, with
/// episodes ending and gestures changing in one half only.
#[test]
fn env_groups_act_and_learn_as_one_round() {
    let mut cfg = crate::bench::tiny_config();
    cfg.ppo.rollout = 4;
    cfg.ppo.minibatches = 2;
    let n = 4;
    let mut whole = Trainer::new(&cfg, n, Device::Cpu).unwrap();
    let mut halves = Trainer::new(&cfg, n, Device::Cpu).unwrap();
    let mut obs = crate::bench::random_obs(n, 64, 1);
    for step in 0..2 * cfg.ppo.rollout + 2 {
        if step > 0 {
            let next = crate::bench::random_obs(n, 64, step as u64 + 1);
            // envs 0 and 1 keep their gesture; 2 and 3 see a new one every step
            let g = obs.gesture.len() / 2;
            obs.gesture[g..].copy_from_slice(&next.gesture[g..]);
            obs.rgb = next.rgb;
            obs.depth = next.depth;
            for (i, e) in obs.envs.iter_mut().enumerate() {
                let ends = i == 1 && step % 3 == 0;
                e.episode_start = i == 1 && step % 3 == 1;
                e.terminated = ends;
                e.reward = if ends { 2.5 } else { -0.01 * (i + step) as f32 };
            }
        }
        let want = whole.step(&obs.batch()).unwrap();
        let (got, updated) = if halves.wants_all() {
            let o = halves.step(&obs.batch()).unwrap();
            (o.actions, o.update.is_some())
        } else {
            let a = halves.step_at(0, &obs.batch_of(0..2)).unwrap();
            let b = halves.step_at(2, &obs.batch_of(2..4)).unwrap();
            assert!(a.update.is_none() && b.update.is_none(), "an update on a group's round");
            let mut both = a.actions;
            both.actions.extend(b.actions.actions);
            both.log_probs.extend(b.actions.log_probs);
            both.values.extend(b.actions.values);
            (both, false)
        };
        assert_eq!(want.update.is_some(), updated, "step {step}");
        assert_eq!(want.actions.actions, got.actions, "step {step}");
        for (w, g) in
            want.actions.log_probs.iter().zip(&got.log_probs).chain(want.actions.values.iter().zip(&got.values))
        {
            assert!((w - g).abs() < 1e-4, "step {step}: {w} against {g}");
        }
    }
    assert_eq!((whole.updates, halves.updates), (2, 2));
    assert_eq!(whole.rollout.rewards, halves.rollout.rewards);
    assert_eq!(whole.rollout.starts, halves.rollout.starts);
    for (a, b) in whole.agent.vs.trainable_variables().iter().zip(&halves.agent.vs.trainable_variables()) {
        assert!(a.allclose(b, 1e-4, 1e-5, false), "the updates differ");
    }
    // a group alone cannot end a rollout: the update needs every env's next observation
    let mut t = Trainer::new(&cfg, n, Device::Cpu).unwrap();
    for _ in 0..cfg.ppo.rollout {
        t.step(&obs.batch()).unwrap();
    }
    let err = t.step_at(0, &obs.batch_of(0..2)).unwrap_err().to_string();
    assert!(err.contains("every env"), "{err}");
}

/// Untimed, a trainer keeps no stage times. Timed, a rollout and its update charge every
/// stage of acting and of the update — on the small CNNs (visual branches in the forward)
/// and on the frozen pretrained encoder (run while preparing the inputs) — and a call's
/// stages never add up to more than its wall time.
#[test]
fn stage_times_fill_every_stage_within_each_call() {
    let dir = tempfile::tempdir().unwrap();
    let weights = crate::bench::random_encoder_weights(dir.path(), 64).unwrap();
    for mut cfg in [crate::bench::tiny_config(), crate::bench::tiny_frozen_config(&weights)] {
        (cfg.ppo.rollout, cfg.ppo.epochs, cfg.model.hidden) = (4, 1, 32);
        let mut t = Trainer::new(&cfg, 2, Device::Cpu).unwrap();
        let obs = crate::bench::random_obs(2, 64, 1);
        t.step(&obs.batch()).unwrap();
        assert_eq!(t.stage_times(), None);
        t.time_stages();
        let sum = |s: farm::profile::StageTimes| s.acting().iter().chain(&s.updating()).map(|(_, v)| v).sum::<f64>();
        // the rollout's other steps, then the call that completes it and updates
        for _ in 0..cfg.ppo.rollout {
            let before = sum(t.stage_times().unwrap());
            let began = Instant::now();
            t.step(&obs.batch()).unwrap();
            let wall = began.elapsed().as_secs_f64();
            let charged = sum(t.stage_times().unwrap()) - before;
            assert!(charged <= wall, "{charged} s of stages in a {wall} s call");
        }
        let s = t.stage_times().unwrap();
        assert_eq!((s.rounds, s.updates), (cfg.ppo.rollout as u64, 1));
        for (name, v) in s.acting().iter().chain(&s.updating()) {
            assert!(*v > 0.0, "{:?}: {name} not charged: {s:?}", cfg.model.encoder);
        }
    }
}

/// `ppo.overlap_update`: a rollout is learned while the next is collected with the weights
/// before it. Its first update, joined when the second rollout is full, gives the weights,
/// moments and minibatch order of the in-place update of the same rollout; every later one
/// reports a policy lag of 1. A checkpoint written while an update is in flight holds the
/// trainer as it was after the last joined one, and a stop learns every rollout collected.
#[test]
fn an_overlapped_update_learns_the_in_place_one_a_rollout_later() {
    let mut cfg = crate::bench::tiny_config();
    (cfg.ppo.rollout, cfg.ppo.minibatches) = (4, 2);
    let t_len = cfg.ppo.rollout;
    let n = 2;
    let mut in_place = Trainer::new(&cfg, n, Device::Cpu).unwrap();
    cfg.ppo.overlap_update = true;
    let mut overlapped = Trainer::new(&cfg, n, Device::Cpu).unwrap();
    let weights = |t: &Trainer| t.agent.vs.trainable_variables().iter().map(|v| v.copy()).collect::<Vec<_>>();
    let mut first = None;
    let mut obs = crate::bench::random_obs(n, 64, 1);
    let dir = tempfile::tempdir().unwrap();
    for step in 0..=3 * t_len {
        if step > 0 {
            let next = crate::bench::random_obs(n, 64, step as u64 + 1);
            (obs.rgb, obs.depth) = (next.rgb, next.depth);
            obs.envs.iter_mut().enumerate().for_each(|(i, e)| e.reward = 0.1 * (i + step % 3) as f32);
        }
        let a = in_place.step(&obs.batch()).unwrap();
        let b = overlapped.step(&obs.batch()).unwrap();
        assert_eq!(a.update.as_ref().map(|m| m.policy_lag), (step % t_len == 0 && step > 0).then_some(0));
        if step == t_len {
            assert!(b.update.is_none(), "nothing was learned yet");
            first = Some((weights(&in_place), in_place.opt.step, in_place.rng.clone()));
        }
        if step == 2 * t_len {
            let m = b.update.as_ref().expect("the first rollout's update, joined");
            assert_eq!((m.update, m.frames, m.policy_lag), (1, (t_len * n) as u64, 0));
            let (w, adam_step, rng) = first.take().unwrap();
            assert!(weights(&overlapped).iter().zip(&w).all(|(a, b)| a.allclose(b, 1e-6, 1e-7, false)));
            assert_eq!((overlapped.opt.step, &overlapped.rng), (adam_step, &rng));
        }
        if step == 2 * t_len + 1 {
            // the second rollout's update is in flight: a checkpoint is the trainer after the first
            let path = dir.path().join("in-flight.safetensors");
            crate::ppo::checkpoint::save_trainer(&path, &overlapped).unwrap();
            let mut resumed = Trainer::new(&cfg, n, Device::Cpu).unwrap();
            crate::ppo::checkpoint::load_trainer(&path, &mut resumed).unwrap();
            assert_eq!(
                (resumed.updates, resumed.frames, resumed.opt.step),
                (1, (t_len * n) as u64, (cfg.ppo.epochs * 2) as i64)
            );
            assert!(weights(&resumed).iter().zip(&weights(&overlapped)).all(|(a, b)| a.equal(b)));
        }
        if step == 3 * t_len {
            let m = b.update.as_ref().expect("the second rollout's update");
            assert_eq!((m.update, m.policy_lag), (2, 1));
        }
    }
    // the third rollout is queued: a stop learns it
    let last = overlapped.settle();
    assert_eq!(last.iter().map(|m| (m.update, m.policy_lag)).collect::<Vec<_>>(), vec![(3, 1)]);
    assert_eq!((overlapped.updates, overlapped.frames), (in_place.updates, in_place.frames));
    assert!(overlapped.settle().is_empty() && in_place.settle().is_empty());
}
