//! Success by how near the target is to the robot's start: the starts give near targets away
//! to a policy that goes to what it sees close by and stops, so a method's gain from the
//! gestures shows where the target is not among the nearest things.

use std::fmt::Write;
use std::path::Path;

use anyhow::Context;
use farm::metrics::{EpisodeResult, scores};
use worker::dataset::{Dataset, Verify};
use worker::program::Program;
use worker::scene::Split;

/// The classes of [`class_of`], in table order.
pub(super) const CLASSES: [&str; 3] = ["the nearest", "2nd–3rd nearest", "farther"];

/// Per program, the target's rank among its room's objects by floor distance from the robot's
/// start (0: it is the nearest).
pub fn target_ranks(ds: &Dataset, programs: &[Program]) -> anyhow::Result<Vec<usize>> {
    let mut rooms: std::collections::BTreeMap<&str, Vec<[f32; 3]>> = Default::default();
    let mut ranks = Vec::with_capacity(programs.len());
    for p in programs {
        if !rooms.contains_key(p.scene.as_str()) {
            let scene = ds.scene(p.scene_id())?;
            rooms.insert(&p.scene, scene.objects.iter().map(|o| o.position).collect());
        }
        ranks.push(rank_among(&rooms[p.scene.as_str()], p));
    }
    Ok(ranks)
}

/// The programs of `split` of the dataset in `dir`, and each one's target rank ([`target_ranks`]).
pub fn program_facts(dir: &Path, split: Split) -> anyhow::Result<(Vec<Program>, Vec<usize>)> {
    let ds = Dataset::open(dir, Verify::Quick).with_context(|| format!("dataset {}", dir.display()))?;
    let programs = ds.index(split)?;
    let ranks = target_ranks(&ds, &programs)?;
    Ok((programs, ranks))
}

fn rank_among(objects: &[[f32; 3]], p: &Program) -> usize {
    let from_start = |q: [f32; 3]| (q[0] - p.robot_pos[0]).hypot(q[2] - p.robot_pos[2]);
    let target = objects.get(p.target_object).map_or(f32::INFINITY, |&q| from_start(q));
    objects.iter().filter(|&&q| from_start(q) < target).count()
}

/// 0: the target is the nearest object, 1: second or third nearest, 2: farther.
pub(super) fn class_of(rank: usize) -> usize {
    match rank {
        0 => 0,
        1 | 2 => 1,
        _ => 2,
    }
}

/// SR at the first stop and with unlimited stops of each evaluation (label, its episodes), by
/// the target's nearness at the start; `ranks` is indexed by the episodes' program.
pub fn markdown(evaluations: &[(String, &[EpisodeResult])], ranks: &[usize]) -> String {
    let mut md = String::from("\n## By the target's nearness at the start\n\n");
    md += "The target's rank among its room's objects by floor distance from the robot's start: a policy \
           that goes to what is near and stops succeeds often where the target is the nearest. \
           SR (%) at the first stop / with unlimited stops, and the programs in each class.\n\n";
    md += &format!("| method | {} |\n|---|---:|---:|---:|\n", CLASSES.join(" | "));
    for (label, eps) in evaluations {
        let mut row = format!("| {label} |");
        for class in 0..CLASSES.len() {
            let of_class: Vec<&EpisodeResult> =
                eps.iter().filter(|e| ranks.get(e.program as usize).is_some_and(|&r| class_of(r) == class)).collect();
            let (first, inf) =
                (scores(of_class.iter().copied(), Some(1), 0.0), scores(of_class.iter().copied(), None, 0.0));
            write!(row, " {:.1} / {:.1} ({}) |", first.sr, inf.sr, of_class.len()).unwrap();
        }
        md += &row;
        md.push('\n');
    }
    md
}

#[cfg(test)]
mod tests {
    use farm::metrics::Stop;

    use super::*;

    fn program(robot: [f32; 3], target_object: usize) -> Program {
        let p = crate::report::tables::tests::program(0, worker::scene::SceneType::Kitchen, 1);
        Program { robot_pos: robot, target_object, ..p }
    }

    /// Succeeds at its first stop when `first`, else at a second stop when `late`.
    fn episode(program: u64, first: bool, late: bool) -> EpisodeResult {
        let mut e = crate::report::tables::tests::result(program, first);
        if !first && late {
            e.stops.push(Stop { step: 12, success: true, distance: 0.5, path_length: 3.0 });
            (e.success, e.num_stops) = (true, 2);
        }
        e
    }

    /// Floor distance only: height does not make an object nearer.
    #[test]
    fn the_rank_counts_the_objects_nearer_on_the_floor() {
        let objects = [[3.0, 0.0, 0.0], [0.0, 9.0, 1.0], [0.0, 0.0, -2.0], [0.0, 0.0, 2.5]];
        assert_eq!(rank_among(&objects, &program([0.0; 3], 1)), 0);
        assert_eq!(rank_among(&objects, &program([0.0; 3], 2)), 1);
        assert_eq!(rank_among(&objects, &program([0.0; 3], 0)), 3);
        // seen from elsewhere the order changes
        assert_eq!(rank_among(&objects, &program([3.0, 0.0, 0.0], 0)), 0);
        assert_eq!([0, 1, 2, 3, 17].map(class_of), [0, 1, 1, 2, 2]);
    }

    #[test]
    fn each_class_scores_its_own_programs_at_one_and_unlimited_stops() {
        let ranks = [0, 0, 1, 5, 2];
        let eps = [episode(0, true, false), episode(1, false, true), episode(2, false, false), episode(3, true, false)];
        let md = markdown(&[("VisSem".into(), &eps)], &ranks);
        // program 4 (2nd–3rd) was not run: its class counts what was
        assert!(md.contains("| VisSem | 50.0 / 100.0 (2) | 0.0 / 0.0 (1) | 100.0 / 100.0 (1) |"), "{md}");
        assert!(md.contains("| method | the nearest | 2nd–3rd nearest | farther |"), "{md}");
    }
}
