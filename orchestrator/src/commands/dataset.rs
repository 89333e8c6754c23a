//! `orchestrator dataset build|stats|export`: make GOND, draw its statistics (Figs 3.8–3.12),
//! export a program in the original folder format.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::{Args, Subcommand};
use indicatif::MultiProgress;

use rayon::prelude::*;
use worker::dataset::build::{BuildOptions, build, default_interventions, synthesize};
use worker::dataset::starts::Starts;
use worker::dataset::{Dataset, Verify};
use worker::gesture::{self, Motion, Pointing};
use worker::program::{Hand, Program};
use worker::scene::{Category, SceneType, Split};

use crate::report::progress::Bar;
use crate::report::{nearness, plot};

#[derive(Subcommand, Debug)]
pub enum DatasetCmd {
    /// Build programs for train/val/test.
    Build(BuildArgs),
    /// Draw the dataset's statistics as PNG figures and a Markdown summary.
    Stats(StatsArgs),
}

#[derive(Args, Debug)]
pub struct BuildArgs {
    /// Folder to build into.
    #[arg(long, default_value = "data/gond")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Train programs in total (the dissertation has about 230,000).
    #[arg(long, default_value_t = 8_000)]
    pub train: u64,
    /// Validation programs per room (20 rooms).
    #[arg(long, default_value_t = 250)]
    pub val_per_room: u64,
    /// Test programs per room (20 rooms).
    #[arg(long, default_value_t = 250)]
    pub test_per_room: u64,
    /// Build only these splits (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "train,val,test")]
    pub splits: Vec<String>,
    /// Replace a dataset already in the folder.
    #[arg(long)]
    pub force: bool,
    /// Worker threads (default: all cores). The output does not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// How cleanly the people point: `clean` (the committed study's level) or `realistic`
    /// (arm-aimed and eye–fingertip-aligned pointing, larger error; docs/usage.md "Gesture realism").
    #[arg(long, default_value = "clean", value_parser = parse_pointing)]
    pub pointing: Pointing,
    /// Where the robot starts: `dissertation` (mean geodesic distance to the target 1.52 m as
    /// §3.3.2, starts already successful allowed) or `far` (uniform 0.5–8 m from the success
    /// region, never successful: datasets before this option, a harder benchmark).
    #[arg(long, default_value = "dissertation", value_parser = parse_starts)]
    pub starts: Starts,
    /// `dissertation` starts: the power k of the distance d in their weight d^k·exp(−β·d) (larger:
    /// fewer starts right at the target, at the same mean).
    #[arg(long, default_value_t = worker::dataset::starts::CALIBRATED_SHAPE)]
    pub start_shape: f32,
}

fn parse_pointing(s: &str) -> Result<Pointing, String> {
    Pointing::from_name(s).ok_or_else(|| format!("`{s}` is not one of clean, realistic"))
}

fn parse_starts(s: &str) -> Result<Starts, String> {
    Starts::from_name(s).ok_or_else(|| format!("`{s}` is not one of dissertation, far"))
}

#[derive(Args, Debug)]
pub struct StatsArgs {
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    /// Where to write the figures and summary (default: DATASET/stats).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(cmd: DatasetCmd) -> anyhow::Result<()> {
    match cmd {
        DatasetCmd::Build(a) => build_cmd(a),
        DatasetCmd::Stats(a) => stats_cmd(a),
    }
}

fn build_cmd(a: BuildArgs) -> anyhow::Result<()> {
    let splits = a
        .splits
        .iter()
        .map(|s| Split::from_name(s).with_context(|| format!("--splits: `{s}` is not one of train, val, test")))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let opts = BuildOptions {
        seed: a.seed,
        train_programs: a.train,
        val_per_room: a.val_per_room,
        test_per_room: a.test_per_room,
        splits,
        pointing: a.pointing,
        starts: a.starts,
        start_shape: a.start_shape,
        ..Default::default()
    };
    let threads = a.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;
    let multi = MultiProgress::new();
    let bars: BTreeMap<Split, Bar> = opts
        .splits
        .iter()
        .map(|&s| {
            let total: u64 = worker::dataset::build::per_room(&opts, s).iter().map(|r| r.1).sum();
            (s, Bar::in_group(&multi, s.name(), total, "programs", Duration::from_secs(10)))
        })
        .collect();
    let t = Instant::now();
    let manifest = pool.install(|| {
        let synth = |seed, human, yaw, target| synthesize(opts.pointing, seed, human, yaw, target);
        build(&a.out, &opts, a.force, &synth, &default_interventions(), &|s, done, _| {
            if let Some(b) = bars.get(&s) {
                b.set(done, "");
            }
        })
    })?;
    for b in bars.values() {
        b.finish();
    }
    let secs = t.elapsed().as_secs_f64();
    let bytes: u64 = std::fs::read_dir(&a.out)?
        .filter_map(|e| e.ok())
        .filter_map(|e| e.metadata().ok())
        .filter(|m| m.is_file())
        .map(|m| m.len())
        .sum();
    let total: u64 = manifest.splits.values().map(|s| s.programs).sum();
    println!(
        "built {} programs in {:.1} s ({:.0} programs/s, {} threads) into {} ({:.1} MB)",
        total,
        secs,
        total as f64 / secs,
        threads,
        a.out.display(),
        bytes as f64 / 1e6
    );
    for (name, s) in &manifest.splits {
        println!(
            "  {name:5}: {:6} programs, {:.1}% with several instances of the target category",
            s.programs,
            100.0 * s.multi_instance_share
        );
    }
    Ok(())
}

fn stats_cmd(a: StatsArgs) -> anyhow::Result<()> {
    let ds = Dataset::open(&a.dataset, Verify::Full)?;
    let out = a.out.unwrap_or_else(|| a.dataset.join("stats"));
    std::fs::create_dir_all(&out)?;
    let mut by_split: BTreeMap<Split, Vec<Program>> = BTreeMap::new();
    let mut lines: BTreeMap<Split, Vec<[f32; 2]>> = BTreeMap::new();
    let mut ranks: BTreeMap<Split, Vec<usize>> = BTreeMap::new();
    for s in Split::ALL {
        if let Some(file) = ds.split(s) {
            let programs = ds.index(s)?;
            lines.insert(s, aiming_lines(file, &programs));
            ranks.insert(s, nearness::target_ranks(&ds, &programs)?);
            by_split.insert(s, programs);
        }
    }
    let summary = write_stats(&by_split, &ds.manifest.build, &lines, &ranks, &out)?;
    println!("{summary}");
    println!("figures and summary in {}", out.display());
    Ok(())
}

/// What the starts give away without the target: how often the target is the object nearest
/// the robot's start, or among the three nearest.
fn nearest_table(ranks: &BTreeMap<Split, Vec<usize>>) -> String {
    let mut md = "\nThe target among its room's objects by floor distance from the robot's start (a policy told no target can learn to go to what is near):\n\n| split | target the nearest object | among the 3 nearest | median rank (1: nearest) |\n|---|---:|---:|---:|\n".to_string();
    for (s, r) in ranks {
        let share = |k: usize| 100.0 * r.iter().filter(|&&x| x < k).count() as f64 / r.len().max(1) as f64;
        let mut sorted = r.clone();
        sorted.sort_unstable();
        let median = sorted.get(sorted.len() / 2).map_or(0, |m| m + 1);
        md += &format!("| {} | {:.1}% | {:.1}% | {} |\n", s.name(), share(1), share(3), median);
    }
    md
}

/// Per program, how far the referencing gesture's shoulder→wrist and forearm lines pass from
/// the target while held (degrees, [`gesture::line_errors`]).
fn aiming_lines(file: &worker::dataset::GondFile, programs: &[Program]) -> Vec<[f32; 2]> {
    let h = worker::humanoid::Humanoid::standard();
    programs
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let motion = Motion::from_flat(&file.motion(i)).expect("a dataset motion has 100 × 95 values");
            let e = gesture::line_errors(h, &motion, p.human_pos.into(), p.human_yaw, p.target_pos.into());
            [e.arm_deg, e.forearm_deg]
        })
        .collect()
}

/// Draws the figures and writes `summary.md`; returns the summary text. `lines` holds each
/// program's aiming-line errors (shoulder→wrist, forearm; degrees) per split, `ranks` each
/// program's target rank by distance from the start ([`nearness::target_ranks`]).
pub fn write_stats(
    by_split: &BTreeMap<Split, Vec<Program>>,
    build: &worker::dataset::BuildParams,
    lines: &BTreeMap<Split, Vec<[f32; 2]>>,
    ranks: &BTreeMap<Split, Vec<usize>>,
    out: &Path,
) -> anyhow::Result<String> {
    let main_split = if by_split.contains_key(&Split::Train) {
        Split::Train
    } else {
        *by_split.keys().next().context("the dataset has no split")?
    };
    let main = &by_split[&main_split];
    types_and_objects(main, main_split, out)?;
    instances(by_split, out)?;
    distances(by_split, out)?;
    let mut md = splits_table(by_split, build);
    md += &pointing_lines(by_split, build, lines);
    md += &nearest_table(ranks);
    md += "\n![scene types](fig3_8_scene_types.png)\n![object types](fig3_9_object_types.png)\n![instances](fig3_11_instances.png)\n![geodesic](fig3_12a_geodesic.png)\n![robot-person](fig3_12b_robot_person.png)\n";
    farm::files::write_atomic(&out.join("summary.md"), md.as_bytes())?;
    Ok(md)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// The share of programs whose target category has more than one instance in the room.
fn multi_share(progs: &[Program]) -> f64 {
    progs.iter().filter(|p| p.instances > 1).count() as f64 / progs.len().max(1) as f64
}

/// Figs. 3.8 and 3.9: programs per scene type and per object type, of the main split.
fn types_and_objects(main: &[Program], main_split: Split, out: &Path) -> anyhow::Result<()> {
    let per_type: Vec<(String, f64)> = SceneType::ALL
        .iter()
        .map(|t| (t.name().to_string(), main.iter().filter(|p| p.scene_type == *t).count() as f64))
        .collect();
    plot::bars(
        &out.join("fig3_8_scene_types.png"),
        &format!("Programs per scene type ({})", main_split.name()),
        "programs",
        &per_type,
    )?;

    // Fig. 3.9: programs per object type.
    let mut per_cat: Vec<(String, f64)> = Category::targets()
        .map(|c| (c.name().to_string(), main.iter().filter(|p| p.target == c).count() as f64))
        .collect();
    per_cat.sort_by(|a, b| b.1.total_cmp(&a.1));
    plot::hbars(
        &out.join("fig3_9_object_types.png"),
        &format!("Programs per object type ({})", main_split.name()),
        "programs",
        &per_cat,
    )?;
    Ok(())
}

/// Fig. 3.11: instances of the target category, per split.
fn instances(by_split: &BTreeMap<Split, Vec<Program>>, out: &Path) -> anyhow::Result<()> {
    let buckets = ["1 instance", "2 instances", "3 instances", "4+ instances"];
    let mut groups: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    for (s, progs) in by_split {
        let mut c = [0f64; 4];
        for p in progs {
            c[(p.instances.clamp(1, 4) - 1) as usize] += 1.0;
        }
        let multi = multi_share(progs);
        groups.push((format!("{} ({:.0}% multi)", s.name(), 100.0 * multi), c.map(|n| (n, 0.0)).to_vec()));
    }
    plot::grouped_bars(
        &out.join("fig3_11_instances.png"),
        "Instances of the target category in the room",
        "programs",
        &buckets,
        &groups,
    )?;
    Ok(())
}

/// Fig. 3.12: geodesic robot start → target's centre (the dissertation's measure: to a
/// success-region cell, then straight; `worker::dataset::starts`) and Euclidean robot–person.
fn distances(by_split: &BTreeMap<Split, Vec<Program>>, out: &Path) -> anyhow::Result<()> {
    let all: Vec<&Program> = by_split.values().flatten().collect();
    let geo: Vec<f64> = all.iter().map(|p| p.target_geodesic as f64).collect();
    let rh: Vec<f64> = all.iter().map(|p| p.robot_human_distance as f64).collect();
    plot::histogram(
        &out.join("fig3_12a_geodesic.png"),
        "Geodesic distance robot start → target (m); the dissertation's mean: 1.52 m",
        "metres",
        &geo,
        0.25,
    )?;
    plot::histogram(
        &out.join("fig3_12b_robot_person.png"),
        "Euclidean distance robot start ↔ person (m)",
        "metres",
        &rh,
        0.25,
    )?;
    Ok(())
}

/// The summary's start: how robots start, and per split its programs, rooms and distances.
fn splits_table(by_split: &BTreeMap<Split, Vec<Program>>, build: &worker::dataset::BuildParams) -> String {
    let starts = match build.starts {
        Starts::Dissertation => format!(
            "`dissertation`: weighted d^{}·exp(−β·d) by their geodesic distance d to the target's centre, β solved per program for a mean of {:.2} m (§3.3.2: 1.52 m), starts already successful allowed",
            build.start_shape, build.start_mean_geodesic
        ),
        Starts::Far => format!(
            "`far`: uniform {}–{} m (geodesic) from the success region, never already successful",
            build.start_geodesic[0], build.start_geodesic[1]
        ),
    };
    let mut md = format!(
        "# GOND statistics\n\nRobot starts {starts}.\n\n| split | programs | rooms | multi-instance share | mean geodesic start → target (m) | mean geodesic to the success region (m) | starts already successful | mean robot–person (m) |\n|---|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for (s, progs) in by_split {
        let rooms: std::collections::BTreeSet<&str> = progs.iter().map(|p| p.scene.as_str()).collect();
        let t: Vec<f64> = progs.iter().map(|p| p.target_geodesic as f64).collect();
        let g: Vec<f64> = progs.iter().map(|p| p.geodesic as f64).collect();
        let d: Vec<f64> = progs.iter().map(|p| p.robot_human_distance as f64).collect();
        let successful = progs.iter().filter(|p| p.starts_successful).count() as f64 / progs.len().max(1) as f64;
        md += &format!(
            "| {} | {} | {} | {:.1}% | {:.2} | {:.2} | {:.1}% | {:.2} |\n",
            s.name(),
            progs.len(),
            rooms.len(),
            100.0 * multi_share(progs),
            mean(&t),
            mean(&g),
            100.0 * successful,
            mean(&d)
        );
    }
    md
}

/// The referencing gestures: their accuracy and hand, and how far the pointing arm's lines pass
/// from the target per split.
fn pointing_lines(
    by_split: &BTreeMap<Split, Vec<Program>>,
    build: &worker::dataset::BuildParams,
    lines: &BTreeMap<Split, Vec<[f32; 2]>>,
) -> String {
    let all: Vec<&Program> = by_split.values().flatten().collect();
    let acc: Vec<f64> = all.iter().map(|p| p.gesture_accuracy as f64).collect();
    let right = all.iter().filter(|p| p.hand == Hand::Right).count() as f64 / all.len().max(1) as f64;
    let mut md = format!(
        "\nReferencing gestures (pointing level `{}`): mean gesture accuracy {:.2} (fraction of frames whose pointing ray passes within {} m of the target), right hand {:.0}%.\n",
        build.pointing.name(),
        mean(&acc),
        gesture::DEFAULT_RADIUS,
        100.0 * right
    );
    md += "\nHow far the pointing arm's lines pass from the target while held (median over the hold, then over programs; the GOND recording: shoulder→wrist 3.8°, forearm 38°):\n\n| split | gesture accuracy | shoulder→wrist (°) | forearm (°) | shoulder→wrist within 10° |\n|---|---:|---:|---:|---:|\n";
    for (s, l) in lines {
        let progs = &by_split[s];
        let median = |k: usize| {
            let mut v: Vec<f32> = l.iter().map(|e| e[k]).collect();
            v.sort_by(f32::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(f32::NAN)
        };
        let within = l.iter().filter(|e| e[0] < 10.0).count() as f64 / l.len().max(1) as f64;
        let acc = mean(&progs.iter().map(|p| p.gesture_accuracy as f64).collect::<Vec<_>>());
        md +=
            &format!("| {} | {:.2} | {:.1} | {:.1} | {:.0}% |\n", s.name(), acc, median(0), median(1), 100.0 * within);
    }
    md
}
