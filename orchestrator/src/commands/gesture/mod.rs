//! A person's own gesture. `orchestrator gesture capture SOURCE --out DIR` reads a video (a
//! folder of frames, or a camera) through MediaPipe Holistic (`landmarks.py`, run by the Python
//! that `scripts/setup.sh` equips) and `worker::gesture::capture`, and writes the recorder's files
//! (metadata JSON and motions/NAME.csv, for `replay` and `follow`), a BVH, the landmarks and
//! `capture.json` (what was found). `orchestrator gesture film PROGRAM --out DIR` renders the avatar performing a
//! program's gesture from a fixed camera, frame by frame: what the closed-loop check captures back.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::Context;
use clap::{Args, Subcommand};
use image::RgbImage;
use nalgebra::{Point3, Vector3};

use worker::camera::Camera;
use worker::geometry::{Part, Shape, heading, yaw_of};
use worker::gesture::capture::{Capture, CaptureOptions, LandmarkFrame, capture};
use worker::gesture::{self, Motion};
use worker::humanoid::Humanoid;
use worker::program::Program;
use worker::render::{RenderConfig, Renderer, View, ViewOut};

use super::program;

#[derive(Subcommand, Debug)]
pub enum GestureCmd {
    /// A person's own gesture from a video, a folder of frames or a camera: the recorder's
    /// files (metadata JSON, motions/NAME.csv), BVH and landmarks.
    Capture(CaptureArgs),
    /// The avatar performing a program's gesture from a fixed camera: PNG frames at 30 fps.
    Film(FilmArgs),
}

#[derive(Args, Debug)]
pub struct CaptureArgs {
    /// A video file, a folder of frames (PNG or JPEG, in name order) or a camera index (0, 1, …).
    pub source: String,
    #[arg(long)]
    pub out: PathBuf,
    /// The program the gesture is recorded into — its room, target, person and robot: SPLIT:INDEX
    /// of the dataset or a recorder metadata JSON.
    #[arg(long, default_value = "val:0")]
    pub program: String,
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    /// Stem of the recorder's files (default: the source's file name).
    #[arg(long)]
    pub name: Option<String>,
    /// Frame rate of a folder of frames (a video file has its own).
    #[arg(long)]
    pub fps: Option<f32>,
    /// How long a camera records.
    #[arg(long, default_value_t = 6.0)]
    pub seconds: f32,
    /// Where the gesturing hand is lost in most frames, keep it relaxed instead of failing.
    #[arg(long)]
    pub hands_optional: bool,
}

#[derive(Args, Debug)]
pub struct FilmArgs {
    /// SPLIT:INDEX of a dataset program, or a recorder metadata JSON (its motion beside it).
    pub program: String,
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    /// Perform intervention gesture K (0..20) instead of the program's referencing gesture.
    #[arg(long)]
    pub intervention: Option<usize>,
    /// Where the camera stands, degrees from the person's front (+ towards their right).
    #[arg(long, default_value_t = 25.0, allow_hyphen_values = true)]
    pub angle: f32,
    #[arg(long, default_value_t = 480)]
    pub size: u32,
}

pub fn run(cmd: GestureCmd) -> anyhow::Result<()> {
    match cmd {
        GestureCmd::Capture(a) => capture_cmd(a),
        GestureCmd::Film(a) => {
            let (_, p, motion, label) = program::resolve(&a.program, &a.dataset, 1)?;
            let motion = match a.intervention {
                Some(k) => {
                    anyhow::ensure!(
                        k < gesture::INTERVENTIONS,
                        "--intervention: {k} is not one of 0..{}",
                        gesture::INTERVENTIONS
                    );
                    gesture::intervention(k)
                }
                None => motion,
            };
            film(&Humanoid::seeded(p.seed), &motion, a.angle, a.size, &a.out)?;
            println!("{label}: {} frames at 30 fps in {}", gesture::FRAMES, a.out.display());
            Ok(())
        }
    }
}

/// Renders `human` performing `motion` (facing +z at the origin, on a grey floor) from a camera
/// `angle` degrees round from their front, 2.4 m away at hip height: `out/000.png` … `099.png`.
pub fn film(human: &Humanoid, motion: &Motion, angle: f32, size: u32, out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    film_frames(human, motion, angle, 2.4, size, |t, img| {
        img.save(out.join(format!("{t:03}.png"))).with_context(|| format!("writing {}", out.display()))
    })
}

/// The frames of [`film`] from `distance` metres away, each handed to `each` with its number as
/// it is drawn.
pub fn film_frames(
    human: &Humanoid,
    motion: &Motion,
    angle: f32,
    distance: f32,
    size: u32,
    mut each: impl FnMut(usize, RgbImage) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let cfg = RenderConfig { width: size, height: size, fov_deg: 60.0, max_views_per_submit: 1 };
    let mut r = Renderer::new(&cfg)?;
    let floor = Part::new(Shape::Box, Point3::new(0.0, -0.01, 0.0), Vector3::new(6.0, 0.01, 6.0), [0.45, 0.45, 0.42]);
    let scene = r.upload_scene(&[floor]);
    let at = heading(angle) * distance;
    let camera = Camera { position: Point3::new(at.x, 0.95, at.y), yaw_deg: yaw_of(-at), pitch_deg: 0.0 };
    let px = (size * size) as usize;
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    for t in 0..gesture::FRAMES {
        let parts = human.parts(&human.pose(motion.frame(t), Point3::origin(), 0.0));
        let views = [View { scene, camera, dynamic: &parts }];
        r.render(&views, &mut [ViewOut { rgb: &mut rgb, depth: &mut depth, ids: None }])?;
        each(t, RgbImage::from_raw(size, size, rgb.clone()).expect("frame size"))?;
    }
    Ok(())
}

/// The landmark script run by setup.sh's Python (`GESTHOR_CAPTURE_PYTHON`) with its model's
/// folder on the path: the command, and the script's temporary file (the caller removes it).
pub fn landmark_command() -> anyhow::Result<(Command, PathBuf)> {
    static STARTED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = STARTED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let script = std::env::temp_dir().join(format!("gesthor-landmarks-{}-{n}.py", std::process::id()));
    std::fs::write(&script, include_str!("landmarks.py")).with_context(|| format!("writing {}", script.display()))?;
    let python = std::env::var("GESTHOR_CAPTURE_PYTHON").unwrap_or_else(|_| "python3".into());
    // setup.sh's folder for the landmark model, unless the environment names another
    let mut path = std::env::var("GESTHOR_CAPTURE_PATH").unwrap_or_else(|_| {
        let deps = std::env::var_os("GESTHOR_DEPS")
            .map(PathBuf::from)
            .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/gesthor")));
        deps.map(|d| d.join("capture")).filter(|d| d.is_dir()).map(|d| d.display().to_string()).unwrap_or_default()
    });
    if let Ok(p) = std::env::var("PYTHONPATH") {
        path = if path.is_empty() { p } else { format!("{path}:{p}") };
    }
    let mut cmd = Command::new(&python);
    cmd.arg(&script).env("PYTHONPATH", path).env("GLOG_minloglevel", "2").env("TF_CPP_MIN_LOG_LEVEL", "3");
    Ok((cmd, script))
}

/// The landmarks of every frame of `source`, written to `out` as the landmark script does.
pub fn landmarks(source: &str, out: &Path, fps: Option<f32>, seconds: f32) -> anyhow::Result<Vec<LandmarkFrame>> {
    let (mut cmd, script) = landmark_command()?;
    cmd.arg(source).arg(out).args(["--seconds", &seconds.to_string()]);
    if let Some(f) = fps {
        cmd.args(["--fps", &f.to_string()]);
    }
    let python = cmd.get_program().to_string_lossy().into_owned();
    let mut child = cmd
        .stderr(Stdio::piped())
        .spawn()
        .with_context(|| format!("starting {python} (GESTHOR_CAPTURE_PYTHON) for the landmark model"))?;
    // progress lines through; the script's `[error]` line (else the last line) says why it failed
    let (mut reason, mut last) = (None, String::new());
    for line in BufReader::new(child.stderr.take().expect("piped")).lines() {
        let line = line.unwrap_or_default();
        if line.starts_with("[capture]") {
            eprintln!("{line}");
        } else if let Some(r) = line.strip_prefix("[error] ") {
            reason = Some(r.to_string());
        } else if !line.trim().is_empty() {
            last = line;
        }
    }
    let last = reason.unwrap_or(last);
    let status = child.wait()?;
    let _ = std::fs::remove_file(&script);
    anyhow::ensure!(status.success(), "{source}: {}", if last.is_empty() { status.to_string() } else { last });
    let text = std::fs::read_to_string(out).with_context(|| format!("reading {}", out.display()))?;
    text.lines()
        .skip(1)
        .enumerate()
        .map(|(i, l)| serde_json::from_str(l).with_context(|| format!("{}: line {}", out.display(), i + 2)))
        .collect()
}

fn capture_cmd(a: CaptureArgs) -> anyhow::Result<()> {
    let (_, p, _, label) = program::resolve(&a.program, &a.dataset, 1)?;
    let name = a.name.clone().unwrap_or_else(|| {
        Path::new(&a.source).file_stem().map_or("camera".into(), |s| s.to_string_lossy().into_owned())
    });
    std::fs::create_dir_all(a.out.join("motions")).with_context(|| format!("creating {}", a.out.display()))?;
    let frames = landmarks(&a.source, &a.out.join("landmarks.jsonl"), a.fps, a.seconds)?;
    let human = Humanoid::seeded(p.seed);
    let c = capture(human.skeleton(), &frames, CaptureOptions { hands_optional: a.hands_optional })
        .map_err(|e| anyhow::anyhow!("{}: {e}", a.source))?;
    let written = write(&a.out, &name, &p, &human, &c)?;
    let (t0, t1) = (c.times[c.span.0], c.times[c.span.1]);
    let side = if c.side == worker::humanoid::Side::Left { "left" } else { "right" };
    let summary = serde_json::json!({
        "source": a.source,
        "program": a.program,
        "metadata": written,
        "motion": a.out.join("motions").join(format!("{name}.csv")),
        "bvh": a.out.join(format!("{name}.bvh")),
        "arm": side,
        "span_seconds": [t0, t1],
        "frames": c.frames.len(),
        "person_frames": c.person_frames,
        "hand_frames": [c.hand_frames.0, c.hand_frames.1],
    });
    farm::files::write_atomic(&a.out.join("capture.json"), serde_json::to_string_pretty(&summary)?.as_bytes())?;
    println!(
        "{}: a {} arm gesture from {t0:.1} to {t1:.1} s ({} of {} frames with a person; the hand seen in {} of {}), \
         recorded into {label}",
        a.source,
        side,
        c.person_frames,
        c.frames.len(),
        c.hand_frames.0,
        c.hand_frames.1
    );
    println!("wrote {}; see it: orchestrator replay {}", written.display(), written.display());
    println!(
        "let a trained agent answer it: orchestrator follow --checkpoint RUN --program {} --motion {} --out {}",
        a.program,
        a.out.join("motions").join(format!("{name}.csv")).display(),
        a.out.join("follow").display()
    );
    Ok(())
}

/// Writes the recorder's files of a captured gesture recorded into program `p`, and its BVH;
/// returns the metadata's path.
fn write(out: &Path, name: &str, p: &Program, human: &Humanoid, c: &Capture) -> anyhow::Result<PathBuf> {
    let (meta, files) = program::metadata(p, name);
    let path = out.join(format!("{name}.json"));
    gesture::motion::write_csv(&out.join(&files[1]), &c.motion)?;
    std::fs::write(out.join(format!("{name}.bvh")), gesture::bvh::export(human, &c.motion))?;
    meta.save(&path)?;
    Ok(path)
}
