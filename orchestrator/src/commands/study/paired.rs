//! `paired.md`: the orderings T4.2 reads (+Both > +Intervention > +Referencing > VisSem) tested
//! program by program and seed by seed, with where each method wins (`report::wins`), from the
//! test outcomes each model keeps (its run folder's, or its record's `test-episodes.csv`).

use std::fmt::Write as _;
use std::path::Path;

use farm::config::RunConfig;
use farm::rooms::Split;

use super::records;
use super::summary::{RunResult, method};
use crate::report::outcomes::Outcome;
use crate::report::wins::{self, ProgramFacts};

/// (first, second) by config stem: the dissertation's orderings, the headline one first.
const PAIRS: [(&str, &str); 4] =
    [("both", "intervention"), ("intervention", "referencing"), ("referencing", "vis_sem"), ("both", "vis_sem")];

/// Per test program: the target's nearness rank and its category's instances, from the
/// study's dataset; None (and a note) when it cannot be read.
pub fn program_facts(cfg: &RunConfig) -> Option<(Vec<usize>, Vec<u32>)> {
    crate::report::nearness::program_facts(&cfg.run.dataset, Split::Test)
        .map(|(programs, ranks)| (ranks, programs.iter().map(|p| p.instances).collect()))
        .map_err(|e| eprintln!("[study] paired.md without nearness and instances: {e:#}"))
        .ok()
}

/// Writes `out/paired.md` for the pairs with a seed in common (nothing when there is none).
pub fn write(out: &Path, results: &[RunResult], facts: Option<&(Vec<usize>, Vec<u32>)>) -> anyhow::Result<()> {
    let of = |stem: &str| -> anyhow::Result<Vec<(u64, Vec<Outcome>)>> {
        let mut models = Vec::new();
        for r in results.iter().filter(|r| r.stem == stem && r.scene_type.is_none()) {
            if let Some(o) = records::outcomes(r)? {
                models.push((r.seed, o));
            }
        }
        models.sort_by_key(|(seed, _)| *seed);
        Ok(models)
    };
    let facts = ProgramFacts { ranks: facts.map(|(r, _)| r.as_slice()), instances: facts.map(|(_, i)| i.as_slice()) };
    let mut md = String::from(
        "# The study's methods paired over test programs and seeds\n\nWritten by `orchestrator study` \
         with its tables, from each model's test episodes.\n\n",
    );
    let mut any = false;
    for (a, b) in PAIRS {
        let (ma, mb) = (of(a)?, of(b)?);
        let label = |stem: &str| method(stem).map_or("?", |m| m.label);
        if let Some(section) = wins::markdown((label(a), &ma), (label(b), &mb), &facts) {
            writeln!(md, "{section}").unwrap();
            any = true;
        }
    }
    if any {
        farm::files::write_atomic(&out.join("paired.md"), md.as_bytes())?;
    }
    Ok(())
}
