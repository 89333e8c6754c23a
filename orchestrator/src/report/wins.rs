//! Two methods paired over test programs and seeds: each seed's model of one against the same
//! seed's model of the other on the same programs (McNemar's test over all the pairs), and where
//! each wins — by the gestures shown at the start, by the target's nearness, by the instances
//! of its category, by whether an intervention corrected the robot before its first stop.

use std::collections::BTreeMap;
use std::fmt::Write;

use farm::metrics::Paired;

use super::outcomes::Outcome;

/// One method's models: (seed, its test outcomes).
pub type Models<'a> = (&'a str, &'a [(u64, Vec<Outcome>)]);

/// What a class of programs is told apart by, when known: per program of the split.
#[derive(Default)]
pub struct ProgramFacts<'a> {
    /// The target's rank by floor distance from the robot's start (0: the nearest object).
    pub ranks: Option<&'a [usize]>,
    /// Instances of the target's category in the room.
    pub instances: Option<&'a [u32]>,
}

/// Both methods' episodes of one (seed, program), normal pass.
struct Pair<'a> {
    a: &'a Outcome,
    b: &'a Outcome,
}

fn pairs<'a>(a: &'a [(u64, Vec<Outcome>)], b: &'a [(u64, Vec<Outcome>)]) -> Vec<(u64, Pair<'a>)> {
    let normal = |v: &'a [Outcome]| -> BTreeMap<u64, &'a Outcome> {
        v.iter().filter(|o| o.pass == "normal").map(|o| (o.program, o)).collect()
    };
    let mut out = Vec::new();
    for (seed, ours) in a {
        let Some((_, theirs)) = b.iter().find(|(s, _)| s == seed) else { continue };
        let theirs = normal(theirs);
        for (program, a) in normal(ours) {
            if let Some(b) = theirs.get(&program) {
                out.push((*seed, Pair { a, b }));
            }
        }
    }
    out
}

fn count<'a>(pairs: impl IntoIterator<Item = &'a Pair<'a>>, first: bool) -> Paired {
    let mut p = Paired::default();
    for x in pairs {
        let (a, b) = if first { (x.a.success_first, x.b.success_first) } else { (x.a.success, x.b.success) };
        p.add(a, b);
    }
    p
}

fn gesture(g: Option<u8>) -> &'static str {
    match g {
        Some(0) => "none",
        Some(1) => "pointing",
        Some(2) => "intervention",
        _ => "?",
    }
}

/// Where a gesture code or flag goes in a table: known values first, unknown last.
fn order(v: Option<u8>) -> usize {
    v.map_or(3, usize::from)
}

fn yes_no(v: Option<bool>) -> &'static str {
    match v {
        Some(true) => "yes",
        Some(false) => "no",
        None => "?",
    }
}

/// The pairing of `a` against `b` as Markdown: `None` when they share no seed.
pub fn markdown(a: Models<'_>, b: Models<'_>, facts: &ProgramFacts<'_>) -> Option<String> {
    let ((la, ma), (lb, mb)) = (a, b);
    let all = pairs(ma, mb);
    if all.is_empty() {
        return None;
    }
    let mut md = per_seed(la, lb, &all);
    where_each_wins(&mut md, la, lb, &all, &classings(la, lb, facts));
    Some(md)
}

/// A class of programs: (its place in the table, its name).
type Class<'p> = Box<dyn Fn(&Pair<'p>) -> Option<(usize, String)> + 'p>;

/// Each seed's pairs (and all seeds') at the first and at unlimited stops, with McNemar's z.
fn per_seed(la: &str, lb: &str, all: &[(u64, Pair<'_>)]) -> String {
    let seeds: Vec<u64> = {
        let mut s: Vec<u64> = all.iter().map(|(s, _)| *s).collect();
        s.dedup();
        s
    };
    let mut md = format!(
        "## {la} against {lb}\n\nEach seed's {la} against the same seed's {lb} on the same test programs (normal \
         pass); z = McNemar's statistic, (only {la} − only {lb}) / √(their sum), |z| > 1.96 at 5%.\n\n\
         | seeds | stops | pairs | both succeed | only {la} | only {lb} | neither | z |\n\
         |---|---|---:|---:|---:|---:|---:|---:|\n"
    );
    let mut rows: Vec<(String, Vec<&Pair<'_>>)> =
        seeds.iter().map(|s| (s.to_string(), all.iter().filter(|(x, _)| x == s).map(|(_, p)| p).collect())).collect();
    if seeds.len() > 1 {
        rows.push(("all".into(), all.iter().map(|(_, p)| p).collect()));
    }
    for (name, ps) in &rows {
        for (first, stops) in [(true, "1"), (false, "∞")] {
            let p = count(ps.iter().copied(), first);
            let (n, z) = (p.programs(), p.mcnemar_z());
            writeln!(
                md,
                "| {name} | {stops} | {n} | {} | {} | {} | {} | {z:.1} |",
                p.both, p.only_first, p.only_second, p.neither
            )
            .unwrap();
        }
    }
    md
}

/// The ways programs are split into classes: the gestures at the start, an intervention before
/// the first stop, and where known the target's nearness and its category's instances.
fn classings<'p>(la: &str, lb: &str, facts: &ProgramFacts<'p>) -> Vec<(String, Class<'p>)> {
    let mut classings: Vec<(String, Class<'p>)> = vec![
        (
            format!("the gesture at the start ({la} / {lb})"),
            Box::new(|p: &Pair<'_>| {
                let (x, y) = (p.a.start_gesture, p.b.start_gesture);
                Some((order(x) * 4 + order(y), format!("{} / {}", gesture(x), gesture(y))))
            }),
        ),
        (
            format!("an intervention before the first stop ({la} / {lb})"),
            Box::new(|p: &Pair<'_>| {
                let (x, y) = (p.a.corrected, p.b.corrected);
                Some((order(x.map(u8::from)) * 4 + order(y.map(u8::from)), format!("{} / {}", yes_no(x), yes_no(y))))
            }),
        ),
    ];
    if let Some(ranks) = facts.ranks {
        classings.push((
            "the target's nearness to the start".into(),
            Box::new(move |p: &Pair<'_>| {
                let class = super::nearness::class_of(*ranks.get(p.a.program as usize)?);
                Some((class, super::nearness::CLASSES[class].to_string()))
            }),
        ));
    }
    if let Some(instances) = facts.instances {
        classings.push((
            "instances of the target's category".into(),
            Box::new(move |p: &Pair<'_>| {
                let n = (*instances.get(p.a.program as usize)? as usize).min(3);
                Some((n, if n == 3 { "3+".into() } else { n.to_string() }))
            }),
        ));
    }
    classings
}

/// Where each wins, at the first stop, over every seed's pairs, class by class.
fn where_each_wins<'p>(
    md: &mut String,
    la: &str,
    lb: &str,
    all: &[(u64, Pair<'p>)],
    classings: &[(String, Class<'p>)],
) {
    write!(
        md,
        "\nWhere each wins, first stop, every seed's pairs: the programs split by …\n\n\
         | by | class | pairs | SR {la} | SR {lb} | only {la} | only {lb} | z |\n|---|---|---:|---:|---:|---:|---:|---:|\n"
    )
    .unwrap();
    for (title, class_of) in classings {
        let mut classes: BTreeMap<(usize, String), Vec<&Pair<'_>>> = BTreeMap::new();
        for (_, p) in all {
            if let Some(c) = class_of(p) {
                classes.entry(c).or_default().push(p);
            }
        }
        let mut title = title.as_str();
        for ((_, class), ps) in classes {
            let p = count(ps.iter().copied(), true);
            let n = p.programs() as f64;
            writeln!(
                md,
                "| {title} | {class} | {} | {:.1} | {:.1} | {} | {} | {:.1} |",
                p.programs(),
                100.0 * (p.both + p.only_first) as f64 / n,
                100.0 * (p.both + p.only_second) as f64 / n,
                p.only_first,
                p.only_second,
                p.mcnemar_z()
            )
            .unwrap();
            title = "";
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn o(program: u64, first: bool, start: u8, corrected: bool) -> Outcome {
        Outcome {
            pass: "normal".into(),
            program,
            success_first: first,
            success: true,
            first_stop: Some(3),
            steps: 9,
            start_gesture: Some(start),
            corrected: Some(corrected),
        }
    }

    #[test]
    fn pairs_are_made_within_a_seed_and_pooled_over_seeds() {
        // seed 1: A wins program 0, B wins program 1; seed 2: A wins both; seed 3 only A ran
        let a = vec![
            (1, vec![o(0, true, 1, false), o(1, false, 1, true)]),
            (2, vec![o(0, true, 1, false), o(1, true, 2, false)]),
            (3, vec![o(0, true, 1, false)]),
        ];
        let b = vec![
            (1, vec![o(0, false, 0, true), o(1, true, 0, true)]),
            (
                2,
                vec![
                    o(0, false, 0, true),
                    o(1, false, 2, true),
                    Outcome { pass: "blind".into(), ..o(1, true, 2, true) },
                ],
            ),
        ];
        let ranks = [0, 5];
        let md = markdown(("+Both", &a), ("+Intervention", &b), &ProgramFacts { ranks: Some(&ranks), instances: None })
            .unwrap();
        assert!(md.contains("| 1 | 1 | 2 | 0 | 1 | 1 | 0 | 0.0 |"), "{md}");
        assert!(md.contains("| 2 | 1 | 2 | 0 | 2 | 0 | 0 | 1.4 |"), "{md}");
        // pooled: 3 wins against 1, z = 2/√4; the blind pass and seed 3 are left out
        assert!(md.contains("| all | 1 | 4 | 0 | 3 | 1 | 0 | 1.0 |"), "{md}");
        assert!(md.contains("| pointing / none | 3 | 66.7 | 33.3 | 2 | 1 |"), "{md}");
        assert!(md.contains("| intervention / intervention | 1 | 100.0 | 0.0 | 1 | 0 |"), "{md}");
        assert!(md.contains("| the target's nearness to the start | the nearest | 2 | 100.0 | 0.0 | 2 | 0 |"), "{md}");
        assert!(!md.contains("instances"), "no instances given: no such split\n{md}");
        assert!(
            markdown(("+Both", &a[2..]), ("+Intervention", &b), &ProgramFacts::default()).is_none(),
            "no seed in common"
        );
    }
}
