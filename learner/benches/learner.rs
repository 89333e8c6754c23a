//! `cargo bench -p learner`: the tiny network's forward on 32 envs and a PPO update on 1280
//! samples (the faithful figures come from `learner bench --faithful`, too slow for criterion
//! on a CPU).

use criterion::{Criterion, criterion_group, criterion_main};
use learner::ppo::trainer::Trainer;
use learner::{ActMode, bench};
use tch::Device;

fn tiny(c: &mut Criterion) {
    let cfg = bench::tiny_config();
    let mut p = learner::Agent::new(&cfg, 32, Device::Cpu).unwrap();
    let o = bench::random_obs(32, 64, 1);
    c.bench_function("tiny act, batch 32", |b| b.iter(|| p.act(&o.batch(), ActMode::Sample).unwrap()));

    let mut t = Trainer::new(&cfg, 10, Device::Cpu).unwrap();
    bench::fill_rollout(&mut t, 3).unwrap();
    let mut g = c.benchmark_group("update");
    g.sample_size(10);
    g.bench_function("tiny PPO update, 1280 samples", |b| b.iter(|| bench::update_once(&mut t)));
    g.finish();
}

criterion_group!(benches, tiny);
criterion_main!(benches);
