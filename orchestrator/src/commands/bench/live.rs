//! `orchestrator bench live`: the speed of `orchestrator live` without a browser. The live loop
//! (a session's step: the policy through `learner act`, the simulator, the page's pictures, the
//! record, each message as JSON) over whole episodes; and the webcam's path, a filmed avatar's
//! gesture sent as 320×240 JPEGs: frame → landmarks per frame, and the captured frames → the 95
//! muscles.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;

use worker::dataset::{Dataset, Verify};
use worker::gesture;
use worker::humanoid::Humanoid;

use crate::commands::gesture::film;
use crate::commands::live::gesture::muscles;
use crate::commands::live::policy::Checkpoint;
use crate::commands::live::session::{Program, Session, Shared};
use crate::commands::live::webcam::Webcam;
use crate::commands::live::wire::{GestureSource, Interventions, ToPage};

#[derive(Args, Debug)]
pub struct BenchLiveArgs {
    /// A checkpoint file or a run directory.
    #[arg(long)]
    pub checkpoint: PathBuf,
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    /// Val programs 0..N run as episodes.
    #[arg(long, default_value_t = 5)]
    pub programs: usize,
    /// Skip the webcam's part (it needs the landmark model that setup.sh installs).
    #[arg(long)]
    pub no_webcam: bool,
    #[arg(long)]
    pub out: PathBuf,
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(((v.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(f64::NAN)
}

pub fn run(a: BenchLiveArgs) -> anyhow::Result<()> {
    let ck = Checkpoint::open(&a.checkpoint)?;
    let size = [ck.cfg.env.width, ck.cfg.env.height];
    let dataset = Arc::new(Dataset::open(&a.dataset, Verify::Quick)?);
    std::fs::create_dir_all(&a.out)?;
    let shared = Arc::new(Shared::new(dataset, vec![ck], a.out.clone()));
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let mut s = Session::new(shared, "bench", tx);

    // the live loop: whole episodes, stepped as fast as they go; each start (the program's
    // dataset and record written, the simulator reset, the person's gestures filmed) timed apart
    let (mut steps, mut busy, mut starts) = (0u64, Duration::ZERO, Vec::new());
    for i in 0..a.programs {
        let t = Instant::now();
        s.start(&Program::Dataset(format!("val:{i}")), 0, None, GestureSource::Program, Interventions::Rule)?;
        starts.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        let mut ended = false;
        while !ended {
            s.step()?;
            steps += 1;
            while let Ok(m) = rx.try_recv() {
                // the socket task's share: each message as the page receives it
                std::hint::black_box(serde_json::to_string(&m)?);
                ended |= matches!(m, ToPage::End(_));
            }
        }
        busy += t.elapsed();
    }
    let steps_per_s = steps as f64 / busy.as_secs_f64();
    let start_ms = percentile(&mut starts, 0.5);
    println!(
        "live loop: {steps} steps of {} episodes at {}×{} in {:.2} s: {steps_per_s:.1} steps/s; \
         an episode's start {start_ms:.0} ms (median)",
        a.programs,
        size[0],
        size[1],
        busy.as_secs_f64()
    );
    let mut report = serde_json::json!({
        "checkpoint": a.checkpoint, "size": size, "episodes": a.programs, "steps": steps,
        "seconds": busy.as_secs_f64(), "steps_per_s": steps_per_s, "start_ms_median": start_ms,
    });

    if !a.no_webcam {
        // val:0's gesture filmed, as a 320×240 webcam would see it
        let (_, p, motion, _) = crate::commands::program::resolve("val:0", &a.dataset, 1)?;
        let frames_dir = a.out.join("film");
        film(&Humanoid::seeded(p.seed), &motion, 25.0, 240, &frames_dir)?;
        let jpegs = (0..gesture::FRAMES)
            .map(|t| webcam_jpeg(&frames_dir.join(format!("{t:03}.png"))))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let mut cam = Webcam::start()?;
        let mut per_frame = Vec::new();
        let mut landmarks = Vec::new();
        for j in &jpegs {
            // one at a time, as the page sends them
            let t = Instant::now();
            landmarks.push(cam.read(j, t)?);
            per_frame.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let t = Instant::now();
        let c = muscles(Humanoid::seeded(p.seed).skeleton(), &landmarks)?;
        let ik_ms = t.elapsed().as_secs_f64() * 1e3;
        let (median, p95) = (percentile(&mut per_frame.clone(), 0.5), percentile(&mut per_frame, 0.95));
        println!(
            "webcam: frame → landmarks {median:.1} ms (median; p95 {p95:.1}) over {} frames of 320×240; \
             the captured {} frames → the 95 muscles {ik_ms:.1} ms",
            jpegs.len(),
            c.frames.len()
        );
        report["webcam"] = serde_json::json!({
            "frames": jpegs.len(), "landmarks_ms_median": median, "landmarks_ms_p95": p95, "muscles_ms": ik_ms,
        });
    }
    let path = a.out.join("bench_live.json");
    farm::files::write_atomic(&path, serde_json::to_string_pretty(&report)?.as_bytes())?;
    println!("wrote {}", path.display());
    Ok(())
}

/// A filmed square frame on a grey 320×240 canvas, as a JPEG (quality 85, as the page sends).
pub fn webcam_jpeg(png: &std::path::Path) -> anyhow::Result<Vec<u8>> {
    let img = image::open(png).with_context(|| png.display().to_string())?.to_rgb8();
    let mut canvas = image::RgbImage::from_pixel(320, 240, image::Rgb([128, 128, 128]));
    let small = image::imageops::resize(&img, 240, 240, image::imageops::FilterType::Triangle);
    image::imageops::overlay(&mut canvas, &small, 40, 0);
    let mut out = Vec::new();
    jpeg_encoder::Encoder::new(&mut out, 85).encode(canvas.as_raw(), 320, 240, jpeg_encoder::ColorType::Rgb)?;
    Ok(out)
}
