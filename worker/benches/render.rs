//! Render throughput on the benchmark room at 224×224 with colour, depth and id readback:
//! views per second at 1, 8 and 16 views per submit.
//!
//! `cargo bench -p worker --bench render` (about 30 s on a 2-core CPU with lavapipe;
//! `GESTHOR_WGPU_BACKEND=gl` measures the OpenGL path instead).

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::Point3;
use worker::render::{RenderConfig, Renderer, View, ViewOut, benchmark_room, figure_parts, spread_cameras};

fn render_views(c: &mut Criterion) {
    let cfg = RenderConfig { max_views_per_submit: 16, ..RenderConfig::default() };
    let mut renderer = match Renderer::new(&cfg) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("skipped: {e}");
            return;
        }
    };
    eprintln!("adapter: {}", renderer.adapter_info());
    let parts = benchmark_room().parts();
    eprintln!("scene: {} parts", parts.len());
    let scene = renderer.upload_scene(&parts);
    let figure = figure_parts(Point3::new(0.3, 0.0, 0.2), 30.0, true);
    let n = cfg.pixels();

    let mut group = c.benchmark_group("render_224");
    group.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(4));
    for k in [1usize, 8, 16] {
        let cameras = spread_cameras(&parts, k);
        let views: Vec<View> = cameras.iter().map(|&camera| View { scene, camera, dynamic: &figure }).collect();
        let mut rgb = vec![0u8; k * n * 3];
        let mut depth = vec![0u16; k * n];
        let mut ids = vec![0u16; k * n];
        group.throughput(Throughput::Elements(k as u64));
        group.bench_function(format!("views_per_submit_{k}"), |b| {
            b.iter(|| {
                renderer.render(black_box(&views), &mut ViewOut::split(&mut rgb, &mut depth, &mut ids, n)).unwrap();
            })
        });
    }
    group.finish();

    // the same figure through the plain function `orchestrator bench sim` uses
    for k in [1usize, 8, 16] {
        let v = worker::render::bench_views(&mut renderer, &parts, k, 2.0).unwrap();
        eprintln!("bench_views: {k:>2} views/submit: {v:8.1} views/s = {:.3} ms/view", 1000.0 / v);
    }
}

criterion_group!(benches, render_views);
criterion_main!(benches);
