//! The study's tables: T4.2 (SR, SPL, DTS at the first stop on test, mean ± std over seeds)
//! beside the dissertation's figures, and which of T4.2's orderings hold on our test split.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use farm::config::Method;
use serde::Serialize;

/// T4.2's methods in the dissertation's order, by config file stem.
pub const METHODS: [(&str, Method); 6] = [
    ("random", Method::Random),
    ("vision_only", Method::VisionOnly),
    ("vis_sem", Method::VisSem),
    ("referencing", Method::Referencing),
    ("intervention", Method::Intervention),
    ("both", Method::Both),
];

/// SR (%), SPL (%), DTS (m) at one number of stops.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Metrics {
    pub sr: f64,
    pub spl: f64,
    pub dts: f64,
}

/// T4.2 as the dissertation prints it (test split, first stop).
pub fn dissertation(m: Method) -> Metrics {
    let (sr, spl, dts) = match m {
        Method::Random => (8.7, 7.1, 2.908),
        Method::VisionOnly => (0.36, 0.098, 2.719),
        Method::VisSem => (15.2, 9.1, 2.419),
        Method::Referencing => (19.2, 11.5, 2.313),
        Method::Intervention => (41.0, 24.8, 2.004),
        Method::Both => (49.2, 28.7, 1.976),
    };
    Metrics { sr, spl, dts }
}

/// T4.2's pairwise orderings (better, worse), as its text and table state them.
pub const ORDERINGS: [(Method, Method); 5] = [
    (Method::Both, Method::Intervention),
    (Method::Intervention, Method::Referencing),
    (Method::Referencing, Method::VisSem),
    (Method::VisSem, Method::VisionOnly),
    (Method::Both, Method::VisSem),
];

/// One evaluated model of the study (a training run's selected checkpoint, or a Random seed).
#[derive(Clone, Debug, Serialize)]
pub struct RunResult {
    pub method: Method,
    pub seed: u64,
    pub checkpoint: String,
    /// SR at the first stop on val of the selected checkpoint (NaN for Random).
    pub val_sr1: f64,
    /// On test, at 1 stop and at unlimited stops.
    pub test_first: Metrics,
    pub test_unlimited: Metrics,
}

impl RunResult {
    pub fn read(
        method: Method,
        seed: u64,
        checkpoint: &Path,
        val_sr1: f64,
        test_csv: &Path,
    ) -> anyhow::Result<RunResult> {
        Ok(RunResult {
            method,
            seed,
            checkpoint: checkpoint.display().to_string(),
            val_sr1,
            test_first: first_stop(test_csv)?,
            test_unlimited: row(test_csv, "inf")?,
        })
    }
}

/// The first-stop row (normal pass, all scene types and instance counts) of `eval`'s tables.csv.
pub fn first_stop(csv: &Path) -> anyhow::Result<Metrics> {
    row(csv, "1")
}

fn row(csv: &Path, stops: &str) -> anyhow::Result<Metrics> {
    let text = std::fs::read_to_string(csv).with_context(|| format!("reading {}", csv.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let col = |name: &str| {
        header.iter().position(|h| *h == name).with_context(|| format!("{}: no column `{name}`", csv.display()))
    };
    let (mode, scene, inst, st) = (col("mode")?, col("scene_type")?, col("instances")?, col("stops")?);
    let (sr, spl, dts) = (col("sr")?, col("spl")?, col("dts")?);
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() == header.len() && f[mode] == "normal" && f[scene] == "all" && f[inst] == "all" && f[st] == stops {
            let num = |i: usize| {
                f[i].parse::<f64>().with_context(|| format!("{}: `{}` is not a number", csv.display(), f[i]))
            };
            return Ok(Metrics { sr: num(sr)?, spl: num(spl)?, dts: num(dts)? });
        }
    }
    anyhow::bail!("{}: no row for the normal pass, all rooms, {stops} stop(s)", csv.display())
}

/// Mean and sample standard deviation (0 for one value).
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = if v.len() > 1 { v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) } else { 0.0 };
    (mean, var.sqrt())
}

fn of(results: &[RunResult], m: Method, f: impl Fn(&RunResult) -> f64) -> Vec<f64> {
    results.iter().filter(|r| r.method == m).map(f).collect()
}

/// Success on training episodes against frames, per method: the mean over the seeds' runs
/// (update by update; every seed makes the same updates) of a 10-update moving mean, in %.
pub fn learning_curves(runs: &[(Method, PathBuf)]) -> anyhow::Result<Vec<(String, Vec<(f64, f64)>)>> {
    #[derive(serde::Deserialize)]
    struct Row {
        frames: f64,
        success_rate: Option<f64>,
    }
    let mut out = Vec::new();
    for (_, m) in METHODS {
        let mut seeds: Vec<Vec<(f64, f64)>> = Vec::new();
        for (_, dir) in runs.iter().filter(|(x, _)| *x == m) {
            let rows: Vec<Row> = farm::files::read_jsonl(&dir.join("metrics.jsonl"))?;
            let smooth: Vec<(f64, f64)> = (0..rows.len())
                .map(|i| {
                    let w: Vec<f64> = rows[i.saturating_sub(9)..=i].iter().filter_map(|r| r.success_rate).collect();
                    (rows[i].frames, if w.is_empty() { 0.0 } else { 100.0 * w.iter().sum::<f64>() / w.len() as f64 })
                })
                .collect();
            seeds.push(smooth);
        }
        let Some(n) = seeds.iter().map(Vec::len).min() else { continue };
        let mean = (0..n).map(|i| (seeds[0][i].0, seeds.iter().map(|s| s[i].1).sum::<f64>() / seeds.len() as f64));
        out.push((m.label().to_string(), mean.collect()));
    }
    Ok(out)
}

/// Writes `T4.2.md`, `T4.2.csv`, `study.json` and two figures into `out`: SR and SPL at the
/// first stop with the seeds' spread (`sr_spl.png`), and every method's training success
/// against frames (`learning_curves.png`, from the runs in `runs`).
pub fn write(out: &Path, results: &[RunResult], runs: &[(Method, PathBuf)]) -> anyhow::Result<()> {
    let mut groups = Vec::new();
    for (_, m) in METHODS {
        let sr = of(results, m, |r| r.test_first.sr);
        if !sr.is_empty() {
            groups.push((m.label().to_string(), vec![mean_std(&sr), mean_std(&of(results, m, |r| r.test_first.spl))]));
        }
    }
    crate::plot::error_bars(
        &out.join("sr_spl.png"),
        "Test, first stop: mean ± std over seeds",
        "%",
        &["SR", "SPL"],
        &groups,
    )?;
    let curves = learning_curves(runs)?;
    if !curves.is_empty() {
        crate::plot::lines(
            &out.join("learning_curves.png"),
            "Success on training episodes (10-update mean, mean over seeds)",
            "frames",
            "success (%)",
            &curves,
        )?;
    }
    let mut md = String::new();
    let mut csv = String::from(
        "method,seeds,sr_mean,sr_std,spl_mean,spl_std,dts_mean,dts_std,sr_inf_mean,dissertation_sr,dissertation_spl,dissertation_dts\n",
    );
    let _ = writeln!(
        md,
        "# T4.2: navigation on test at the first stop\n\nOurs: mean ± std over seeds, each the checkpoint with the best SR at the first stop \
         on val; separately trained models per method. Dissertation: its Table 4.2.\n"
    );
    let _ = writeln!(
        md,
        "| method | seeds | SR (%) | SPL (%) | DTS (m) | SR ∞ (%) | dissertation SR / SPL / DTS |\n|---|---:|---:|---:|---:|---:|---:|"
    );
    for (_, m) in METHODS {
        let sr = of(results, m, |r| r.test_first.sr);
        if sr.is_empty() {
            continue;
        }
        let (srm, srs) = mean_std(&sr);
        let (splm, spls) = mean_std(&of(results, m, |r| r.test_first.spl));
        let (dtsm, dtss) = mean_std(&of(results, m, |r| r.test_first.dts));
        let (infm, infs) = mean_std(&of(results, m, |r| r.test_unlimited.sr));
        let d = dissertation(m);
        let _ = writeln!(
            md,
            "| {} | {} | {srm:.1} ± {srs:.1} | {splm:.1} ± {spls:.1} | {dtsm:.2} ± {dtss:.2} | {infm:.1} ± {infs:.1} | {} / {} / {} |",
            m.label(),
            sr.len(),
            d.sr,
            d.spl,
            d.dts
        );
        let _ = writeln!(
            csv,
            "{},{},{srm:.3},{srs:.3},{splm:.3},{spls:.3},{dtsm:.4},{dtss:.4},{infm:.3},{},{},{}",
            m.label(),
            sr.len(),
            d.sr,
            d.spl,
            d.dts
        );
    }
    let _ = writeln!(
        md,
        "\n## T4.2's orderings on our test split\n\nHolds when our mean SR at the first stop is higher by more than the larger of the two \
         methods' standard deviations over seeds.\n\n| ordering | ours (SR %) | holds |\n|---|---:|:---:|"
    );
    for (a, b) in ORDERINGS {
        let (xa, xb) = (of(results, a, |r| r.test_first.sr), of(results, b, |r| r.test_first.sr));
        if xa.is_empty() || xb.is_empty() {
            continue;
        }
        let ((ma, sa), (mb, sb)) = (mean_std(&xa), mean_std(&xb));
        let verdict = if ma - mb > sa.max(sb) {
            "yes"
        } else if ma > mb {
            "within the spread"
        } else {
            "no"
        };
        let _ = writeln!(md, "| {} > {} | {ma:.1} ± {sa:.1} vs {mb:.1} ± {sb:.1} | {verdict} |", a.label(), b.label());
    }
    let _ = writeln!(
        md,
        "\n## Runs\n\n| method | seed | selected checkpoint | val SR 1 stop (%) | test SR 1 stop (%) |\n|---|---:|---|---:|---:|"
    );
    for r in results {
        let val = if r.val_sr1.is_nan() { "-".into() } else { format!("{:.1}", r.val_sr1) };
        let _ =
            writeln!(md, "| {} | {} | {} | {val} | {:.1} |", r.method.label(), r.seed, r.checkpoint, r.test_first.sr);
    }
    let _ = writeln!(md, "\n![SR and SPL](sr_spl.png)\n\n![learning curves](learning_curves.png)");
    farm::files::write_atomic(&out.join("T4.2.md"), md.as_bytes())?;
    farm::files::write_atomic(&out.join("T4.2.csv"), csv.as_bytes())?;
    farm::files::write_atomic(&out.join("study.json"), serde_json::to_string_pretty(results)?.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_and_sample_std() {
        assert_eq!(mean_std(&[2.0]), (2.0, 0.0));
        let (m, s) = mean_std(&[1.0, 3.0]);
        assert_eq!(m, 2.0);
        assert!((s - 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn reads_the_first_stop_row_and_names_the_file_when_it_cannot() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("tables.csv");
        std::fs::write(
            &p,
            "label,split,mode,scene_type,instances,stops,episodes,sr,spl,dts\n\
             +Both,test,normal,Kitchen,all,1,250,9.0,8.0,1.0\n\
             +Both,test,normal,all,all,1,1000,3.700,3.138,1.1750\n\
             +Both,test,normal,all,all,inf,1000,52.300,37.434,0.2572\n",
        )
        .unwrap();
        assert_eq!(first_stop(&p).unwrap(), Metrics { sr: 3.7, spl: 3.138, dts: 1.175 });
        assert_eq!(row(&p, "inf").unwrap().sr, 52.3);
        let e = row(&p, "2").unwrap_err().to_string();
        assert!(e.contains("tables.csv") && e.contains("2 stop"), "{e}");
    }

    #[test]
    fn the_table_puts_the_dissertation_beside_ours_and_judges_orderings() {
        let dir = tempfile::tempdir().unwrap();
        let r = |m, seed, sr| RunResult {
            method: m,
            seed,
            checkpoint: "c".into(),
            val_sr1: 1.0,
            test_first: Metrics { sr, spl: sr / 2.0, dts: 1.0 },
            test_unlimited: Metrics { sr: 50.0, spl: 30.0, dts: 0.3 },
        };
        let results =
            [r(Method::Both, 1, 10.0), r(Method::Both, 2, 12.0), r(Method::VisSem, 1, 4.0), r(Method::VisSem, 2, 5.0)];
        write(dir.path(), &results, &[]).unwrap();
        assert!(dir.path().join("sr_spl.png").is_file());
        let md = std::fs::read_to_string(dir.path().join("T4.2.md")).unwrap();
        assert!(md.contains("| +Both | 2 | 11.0 ± 1.4 |") && md.contains("49.2 / 28.7 / 1.976"), "{md}");
        assert!(md.contains("| +Both > VisSem | 11.0 ± 1.4 vs 4.5 ± 0.7 | yes |"), "{md}");
        let csv = std::fs::read_to_string(dir.path().join("T4.2.csv")).unwrap();
        assert_eq!(csv.lines().count(), 3);
    }
}
