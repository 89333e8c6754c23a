//! Gesture and humanoid hot paths: synthesizing a referencing gesture (the dataset builder
//! makes one per program), posing and drawing the person (once per rendered frame), and
//! gesture accuracy (100 poses).
//!
//! `cargo bench -p worker --bench gesture`

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::Point3;
use worker::geometry::heading;
use worker::gesture::{self, DEFAULT_RADIUS, STANDING};
use worker::humanoid::Humanoid;

/// A target 1–5 m away within ±100° of the person's heading, drawn from the seed.
fn scene(seed: u64) -> (Point3<f32>, f32, Point3<f32>) {
    let f = |k: u64| (farm::seed::mix(seed, &[k]) % 10_000) as f32 / 10_000.0;
    let pos = Point3::new(f(1) * 6.0 - 3.0, 0.0, f(2) * 6.0 - 3.0);
    let yaw = f(3) * 360.0;
    let h = heading(yaw + f(4) * 200.0 - 100.0) * (1.0 + 4.0 * f(5));
    (pos, yaw, Point3::new(pos.x + h.x, 2.0 * f(6), pos.z + h.y))
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("gesture");
    g.throughput(Throughput::Elements(1));
    let scenes: Vec<_> = (0..256).map(scene).collect();
    let mut seed = 0u64;
    g.bench_function("referencing", |b| {
        b.iter(|| {
            seed += 1;
            let (p, y, t) = scenes[(seed % 256) as usize];
            black_box(gesture::referencing(seed, p, y, t))
        })
    });
    g.bench_function("intervention", |b| {
        let mut i = 0;
        b.iter(|| {
            i = (i + 1) % gesture::INTERVENTIONS;
            black_box(gesture::intervention(i))
        })
    });
    let h = Humanoid::seeded(1);
    let (motion, _) = gesture::referencing(1, Point3::origin(), 0.0, Point3::new(1.0, 1.0, 2.0));
    g.bench_function("pose", |b| {
        let mut t = 0;
        b.iter(|| {
            t = (t + 1) % gesture::FRAMES;
            black_box(h.pose(motion.frame(t), Point3::origin(), 30.0))
        })
    });
    g.bench_function("pose+parts", |b| {
        let mut t = 0;
        b.iter(|| {
            t = (t + 1) % gesture::FRAMES;
            let p = h.pose(motion.frame(t), Point3::origin(), 30.0);
            black_box(h.parts(&p))
        })
    });
    g.bench_function("accuracy", |b| {
        b.iter(|| {
            black_box(gesture::accuracy::accuracy_with(
                &h,
                &motion,
                Point3::origin(),
                0.0,
                Point3::new(1.0, 1.0, 2.0),
                DEFAULT_RADIUS,
            ))
        })
    });
    g.bench_function("standing-pose", |b| b.iter(|| black_box(h.pose(black_box(&STANDING), Point3::origin(), 0.0))));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
