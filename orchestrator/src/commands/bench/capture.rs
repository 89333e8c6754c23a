//! `orchestrator bench capture`: the closed loop of `gesture capture`. The avatar performing
//! dataset programs' referencing gestures (and, given, the real GOND recording) is filmed from a
//! fixed camera, captured back through the landmark model and the inverse kinematics, and the
//! recovered pointing line (shoulder → wrist) compared with the original's during the hold:
//! from the landmarks alone and after the inverse kinematics.

use std::fmt::Write as _;
use std::path::PathBuf;

use clap::Args;

use worker::gesture::capture::{CaptureOptions, arm_activity, capture, observed_pointing_line, pointing_line};
use worker::humanoid::{Humanoid, Side};

use crate::commands::gesture::{film, landmarks};
use crate::commands::program;

#[derive(Args, Debug)]
pub struct BenchCaptureArgs {
    /// Val programs 0..N filmed.
    #[arg(long, default_value_t = 12)]
    pub programs: usize,
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    /// Also this recording (a recorder metadata JSON, its motion beside it), e.g. the GOND sample.
    #[arg(long)]
    pub recording: Option<PathBuf>,
    /// The camera, degrees round from the person's front (+ towards their right).
    #[arg(long, default_value_t = 25.0, allow_hyphen_values = true)]
    pub angle: f32,
    #[arg(long, default_value_t = 480)]
    pub size: u32,
    #[arg(long)]
    pub out: PathBuf,
}

/// One filmed gesture's errors during its hold (degrees), None where nothing was recovered.
#[derive(Debug, serde::Serialize)]
pub struct Row {
    pub program: String,
    pub arm_found: bool,
    pub hold_frames: usize,
    /// Median angle between the original's and the landmarks' shoulder → wrist lines.
    pub landmarks_deg: Option<f32>,
    /// The same after the inverse kinematics (the captured muscles).
    pub captured_deg: Option<f32>,
    /// Share of the gesture's frames with the hand seen.
    pub hand_seen: f32,
}

fn median(mut v: Vec<f32>) -> Option<f32> {
    v.sort_by(f32::total_cmp);
    (!v.is_empty()).then(|| v[v.len() / 2])
}

pub fn run(a: BenchCaptureArgs) -> anyhow::Result<()> {
    let mut sources: Vec<String> = (0..a.programs).map(|i| format!("val:{i}")).collect();
    sources.extend(a.recording.iter().map(|p| p.display().to_string()));
    let mut rows = Vec::new();
    for (k, src) in sources.iter().enumerate() {
        let row = one_gesture(&a, k, src)?;
        eprintln!("[bench] {}/{}: {row:?}", k + 1, sources.len());
        rows.push(row);
    }
    let md = markdown(&a, &rows);
    std::fs::write(a.out.join("capture.md"), &md)?;
    std::fs::write(a.out.join("capture.json"), serde_json::to_string_pretty(&rows)?)?;
    print!("{md}");
    Ok(())
}

/// Films gesture `src` from the bench's angle, reads it back and captures it: its row.
fn one_gesture(a: &BenchCaptureArgs, k: usize, src: &str) -> anyhow::Result<Row> {
    let (_, p, motion, label) = program::resolve(src, &a.dataset, 1)?;
    let human = Humanoid::seeded(p.seed);
    let sk = human.skeleton();
    let dir = a.out.join(format!("{k:02}"));
    film(&human, &motion, a.angle, a.size, &dir.join("frames"))?;
    let frames = landmarks(&dir.join("frames").display().to_string(), &dir.join("landmarks.jsonl"), Some(30.0), 0.0)?;
    let (side, act) = arm_activity(sk, &motion);
    let s = if side == Side::Left { 0 } else { 1 };
    let peak = act[s].iter().copied().fold(0.0f32, f32::max);
    let hold: Vec<usize> = (0..act[s].len()).filter(|&i| act[s][i] >= 0.8 * peak).collect();
    let original = |i: usize| pointing_line(sk, motion.frame(i), side);
    let lm: Vec<f32> = hold
        .iter()
        .filter_map(|&i| Some(original(i).angle(&observed_pointing_line(sk, frames.get(i)?, side)?).to_degrees()))
        .collect();
    Ok(match capture(sk, &frames, CaptureOptions { hands_optional: true }) {
        Ok(c) => Row {
            program: label,
            arm_found: c.side == side,
            hold_frames: hold.len(),
            landmarks_deg: median(lm),
            captured_deg: median(
                hold.iter()
                    .filter_map(|&i| Some(original(i).angle(&pointing_line(sk, c.frames.get(i)?, side))))
                    .map(f32::to_degrees)
                    .collect(),
            ),
            hand_seen: c.hand_frames.0 as f32 / c.hand_frames.1.max(1) as f32,
        },
        Err(e) => {
            eprintln!("[bench] {label}: {e}");
            Row {
                program: label,
                arm_found: false,
                hold_frames: hold.len(),
                landmarks_deg: median(lm),
                captured_deg: None,
                hand_seen: 0.0,
            }
        }
    })
}

/// The table of every gesture's angles, and their medians over the dataset's gestures.
fn markdown(a: &BenchCaptureArgs, rows: &[Row]) -> String {
    let fmt = |v: Option<f32>| v.map_or("-".into(), |v| format!("{v:.1}"));
    let mut md = format!(
        "# Closed loop of `gesture capture` ({} gestures, camera {}° from the front, {}²)\n\n\
         Median angle (°) during the hold between the original's shoulder→wrist line and the recovered one.\n\n\
         | program | arm found | hold frames | landmarks | captured | hand seen |\n|---|:---:|---:|---:|---:|---:|\n",
        rows.len(),
        a.angle,
        a.size
    );
    for r in rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {:.0}% |",
            r.program,
            if r.arm_found { "yes" } else { "no" },
            r.hold_frames,
            fmt(r.landmarks_deg),
            fmt(r.captured_deg),
            100.0 * r.hand_seen
        );
    }
    let synth: Vec<&Row> = rows.iter().take(a.programs).collect();
    let med = |f: &dyn Fn(&Row) -> Option<f32>| median(synth.iter().filter_map(|r| f(r)).collect());
    let _ = writeln!(
        md,
        "\nOver the {} dataset gestures: median {} ° from the landmarks, {} ° captured; the arm found in {} of {}.",
        synth.len(),
        fmt(med(&|r| r.landmarks_deg)),
        fmt(med(&|r| r.captured_deg)),
        synth.iter().filter(|r| r.arm_found).count(),
        synth.len()
    );
    md
}
