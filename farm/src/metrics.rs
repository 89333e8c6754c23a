//! Navigation metrics (§4.4.1): success rate (SR), success weighted by path length (SPL,
//! Anderson et al.) and distance to success (DTS), at 1, 2, 3 and unlimited stops.
//!
//! Episodes run with unlimited stops; the metric "at k stops" reads the episode as if it had
//! ended at its k-th stop: success only if it happened by the k-th stop, SPL from the path
//! length at that stop, DTS from the distance where the episode would have ended (the k-th
//! stop, or the end of the episode if it stopped fewer times).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use shm_schema::{EnvRecord, SUMMARY_STOPS, action};

/// One finished episode, as the learner records it (`episodes.jsonl`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeResult {
    /// Program index within the split.
    pub program: u64,
    pub worker: u32,
    pub env: u32,
    pub generation: u32,
    pub steps: u32,
    pub success: bool,
    pub collisions: u32,
    pub num_stops: u32,
    pub path_length: f32,
    /// l_i: a lower bound of any successful path's length from the start (older files call it
    /// `start_geodesic`, the 8-connected grid distance of earlier versions).
    #[serde(alias = "start_geodesic")]
    pub shortest_path: f32,
    pub final_distance: f32,
    pub total_reward: f32,
    pub intervention_steps: u32,
    /// The first stops (up to 3): (step, success, distance, path length).
    pub stops: Vec<Stop>,
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stop {
    pub step: u32,
    pub success: bool,
    pub distance: f32,
    pub path_length: f32,
}

/// SPL of one successful episode (Anderson et al.): l / max(p, l), with l the shortest path and
/// p the path taken; 1 when the robot started inside the success region and never moved.
pub fn spl(shortest: f64, taken: f64) -> f64 {
    if shortest <= 0.0 && taken <= 0.0 { 1.0 } else { shortest / taken.max(shortest) }
}

/// One step of a recorded episode: the robot's pose when it observed, the action it then took
/// (255 for the final observation), the gesture it perceived (0 none, 1 referencing,
/// 2 intervention) and which intervention.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryStep {
    pub x: f32,
    pub z: f32,
    pub yaw: f32,
    pub action: u8,
    pub gesture: u8,
    pub intervention: u8,
}

/// One evaluation episode step by step (a line of `trajectories.jsonl`), for pictures like
/// Figs 4.2/4.3.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Trajectory {
    pub program: u64,
    pub worker: u32,
    pub env: u32,
    pub success: bool,
    pub steps: Vec<TrajectoryStep>,
}

impl Trajectory {
    /// Adds one observation of the env's current episode; returns the whole trajectory when
    /// this observation ends it. A record that starts an episode begins a new trajectory (so a
    /// restarted worker's unfinished episode is forgotten).
    pub fn record(&mut self, r: &EnvRecord, worker: u32, env: u32) -> Option<Trajectory> {
        if r.episode_start != 0 || self.program != r.program || self.worker != worker || self.env != env {
            *self = Trajectory { program: r.program, worker, env, success: false, steps: Vec::with_capacity(128) };
        }
        if let Some(prev) = self.steps.last_mut() {
            prev.action = r.last_action.min(action::NONE as u32) as u8;
        }
        self.steps.push(TrajectoryStep {
            x: r.robot[0],
            z: r.robot[1],
            yaw: r.robot[2],
            action: action::NONE,
            gesture: r.gesture_kind,
            intervention: r.gesture_index,
        });
        if r.terminated != 0 || r.truncated != 0 {
            self.success = r.summary.success != 0;
            return Some(std::mem::take(self));
        }
        None
    }
}

impl EpisodeResult {
    /// From the record of an episode's final observation.
    pub fn from_record(r: &EnvRecord, worker: u32, env: u32, generation: u32) -> EpisodeResult {
        let s = &r.summary;
        EpisodeResult {
            program: r.program,
            worker,
            env,
            generation,
            steps: s.steps,
            success: s.success != 0,
            collisions: s.collisions,
            num_stops: s.num_stops,
            path_length: s.path_length,
            shortest_path: s.shortest_path,
            final_distance: s.final_distance,
            total_reward: s.total_reward,
            intervention_steps: s.intervention_steps,
            stops: s
                .stops
                .iter()
                .take((s.num_stops as usize).min(SUMMARY_STOPS))
                .map(|st| Stop {
                    step: st.step,
                    success: st.success != 0,
                    distance: st.distance,
                    path_length: st.path_length,
                })
                .collect(),
        }
    }

    /// (success, SPL, distance at the end) when at most `k` stops are allowed (None = ∞).
    pub fn at_stops(&self, k: Option<usize>) -> (bool, f64, f64) {
        let l = self.shortest_path as f64;
        let spl = |p: f64| spl(l, p);
        match k {
            None => {
                let spl = if self.success { spl(self.path_length as f64) } else { 0.0 };
                (self.success, spl, self.final_distance as f64)
            }
            Some(k) => {
                assert!(k >= 1 && k <= SUMMARY_STOPS, "metrics keep the first {SUMMARY_STOPS} stops");
                match self.stops.iter().take(k).find(|s| s.success) {
                    Some(s) => (true, spl(s.path_length as f64), s.distance as f64),
                    None => {
                        let d = self.stops.get(k - 1).map_or(self.final_distance, |s| s.distance);
                        (false, 0.0, d as f64)
                    }
                }
            }
        }
    }
}

/// SR (%), SPL (%), DTS (m) over a set of episodes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    pub episodes: usize,
    pub sr: f64,
    pub spl: f64,
    pub dts: f64,
}

/// Scores at `k` stops with DTS threshold `threshold` (DTS = max(0, d − threshold)).
pub fn scores<'a>(episodes: impl IntoIterator<Item = &'a EpisodeResult>, k: Option<usize>, threshold: f64) -> Scores {
    let (mut n, mut sr, mut spl, mut dts) = (0usize, 0.0, 0.0, 0.0);
    for e in episodes {
        let (s, p, d) = e.at_stops(k);
        n += 1;
        sr += s as u32 as f64;
        spl += p;
        dts += (d - threshold).max(0.0);
    }
    if n == 0 {
        return Scores::default();
    }
    let n_f = n as f64;
    Scores { episodes: n, sr: 100.0 * sr / n_f, spl: 100.0 * spl / n_f, dts: dts / n_f }
}

/// The 95% Wilson score interval of a binomial proportion, in % (`successes` of `n`): the
/// interval a rate measured on n episodes leaves for the true rate.
pub fn wilson95(successes: usize, n: usize) -> (f64, f64) {
    if n == 0 {
        return (0.0, 100.0);
    }
    let (z, n_f) = (1.959_964f64, n as f64);
    let p = successes as f64 / n_f;
    let centre = (p + z * z / (2.0 * n_f)) / (1.0 + z * z / n_f);
    let half = z / (1.0 + z * z / n_f) * (p * (1.0 - p) / n_f + z * z / (4.0 * n_f * n_f)).sqrt();
    (100.0 * (centre - half).max(0.0), 100.0 * (centre + half).min(1.0))
}

/// Two evaluations of the same programs, episode by episode (success at `k` stops): how many
/// succeed in both, only in the first, only in the second, in neither. Programs in only one are
/// left out.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Paired {
    pub both: usize,
    pub only_first: usize,
    pub only_second: usize,
    pub neither: usize,
}

impl Paired {
    pub fn of(first: &[EpisodeResult], second: &[EpisodeResult], k: Option<usize>) -> Paired {
        let second: BTreeMap<u64, &EpisodeResult> = second.iter().map(|e| (e.program, e)).collect();
        let mut p = Paired::default();
        for a in first {
            let Some(b) = second.get(&a.program) else { continue };
            p.add(a.at_stops(k).0, b.at_stops(k).0);
        }
        p
    }

    /// Counts one program: whether the first and the second succeeded on it.
    pub fn add(&mut self, first: bool, second: bool) {
        match (first, second) {
            (true, true) => self.both += 1,
            (true, false) => self.only_first += 1,
            (false, true) => self.only_second += 1,
            (false, false) => self.neither += 1,
        }
    }

    pub fn programs(&self) -> usize {
        self.both + self.only_first + self.only_second + self.neither
    }

    /// McNemar's statistic as a normal deviate, (only first − only second) / √(their sum):
    /// whether one succeeds where the other fails more often than chance would (|z| > 1.96 at 5%).
    pub fn mcnemar_z(&self) -> f64 {
        let discordant = (self.only_first + self.only_second) as f64;
        if discordant == 0.0 { 0.0 } else { (self.only_first as f64 - self.only_second as f64) / discordant.sqrt() }
    }
}

/// How a policy uses its first stop: whether it stops where a stop can succeed (T4.4's
/// first-stop to unlimited-stops ratio; the dissertation's is 0.16–0.46).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FirstStops {
    pub episodes: usize,
    /// Episodes with at least one stop.
    pub stopped: usize,
    /// Successful first stops.
    pub successes: usize,
    /// First stops within `within` metres of the target (in view or not).
    pub near: usize,
    pub within: f64,
    /// Successful episodes with unlimited stops.
    pub successes_any: usize,
    /// Mean step of the first stop, over the episodes that stopped.
    pub mean_step: f64,
}

impl FirstStops {
    pub fn of<'a>(episodes: impl IntoIterator<Item = &'a EpisodeResult>, within: f64) -> FirstStops {
        let mut f = FirstStops { within, ..Default::default() };
        let mut steps = 0.0;
        for e in episodes {
            f.episodes += 1;
            f.successes_any += e.success as usize;
            if let Some(s) = e.stops.first() {
                f.stopped += 1;
                f.successes += s.success as usize;
                f.near += ((s.distance as f64) < within) as usize;
                steps += s.step as f64;
            }
        }
        f.mean_step = if f.stopped > 0 { steps / f.stopped as f64 } else { 0.0 };
        f
    }

    /// Share of first stops within `within` of the target (%).
    pub fn near_share(&self) -> f64 {
        if self.stopped == 0 { 0.0 } else { 100.0 * self.near as f64 / self.stopped as f64 }
    }

    /// Share of episodes with at least one stop (%).
    pub fn stopped_share(&self) -> f64 {
        100.0 * self.stopped as f64 / self.episodes.max(1) as f64
    }

    /// SR at the first stop over SR with unlimited stops (0 when nothing succeeds).
    pub fn ratio(&self) -> f64 {
        if self.successes_any == 0 { 0.0 } else { self.successes as f64 / self.successes_any as f64 }
    }

    /// SR at the first stop (%) and its 95% interval.
    pub fn sr(&self) -> (f64, (f64, f64)) {
        let sr = if self.episodes == 0 { 0.0 } else { 100.0 * self.successes as f64 / self.episodes as f64 };
        (sr, wilson95(self.successes, self.episodes))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_interval_matches_the_textbook() {
        // 87 of 1,000: 7.11%–10.61% (Wilson, z = 1.96)
        let (lo, hi) = wilson95(87, 1000);
        assert!((lo - 7.11).abs() < 0.01 && (hi - 10.61).abs() < 0.01, "{lo} {hi}");
        let (lo, hi) = wilson95(0, 50);
        assert_eq!(lo, 0.0);
        assert!((hi - 7.13).abs() < 0.02, "{hi}");
    }

    #[test]
    fn first_stops_count_where_the_first_stop_was() {
        let eps = [
            ep(true, 2.0, 3.0, vec![stop(true, 0.8, 3.0)], 0.8),
            ep(true, 2.0, 5.0, vec![stop(false, 2.5, 1.0), stop(true, 0.9, 5.0)], 0.9),
            ep(false, 2.0, 1.0, vec![stop(false, 0.7, 1.0)], 0.7),
            ep(false, 2.0, 1.0, vec![], 3.0),
        ];
        let f = FirstStops::of(&eps, 1.0);
        assert_eq!((f.episodes, f.stopped, f.successes, f.near, f.successes_any), (4, 3, 1, 2, 2));
        assert!((f.near_share() - 200.0 / 3.0).abs() < 1e-9);
        assert_eq!(f.ratio(), 0.5);
        assert_eq!(f.sr().0, 25.0);
    }

    #[test]
    fn paired_episodes_match_by_program() {
        let at = |program: u64, first: bool, any: bool| EpisodeResult {
            program,
            ..ep(any, 2.0, 3.0, vec![stop(first, if first { 0.5 } else { 2.0 }, 1.0)], 0.5)
        };
        // program 3 is in the first evaluation only: left out
        let a = [at(0, true, true), at(1, true, true), at(2, false, true), at(3, true, true)];
        let b = [at(2, true, true), at(1, false, false), at(0, true, true)];
        let first = Paired::of(&a, &b, Some(1));
        assert_eq!(first, Paired { both: 1, only_first: 1, only_second: 1, neither: 0 });
        assert_eq!((first.programs(), first.mcnemar_z()), (3, 0.0));
        let any = Paired::of(&a, &b, None);
        assert_eq!(any, Paired { both: 2, only_first: 1, only_second: 0, neither: 0 });
        assert_eq!(any.mcnemar_z(), 1.0);
        // 169 against 63 discordant pairs: z = 106 / √232
        let z = Paired { both: 682, only_first: 169, only_second: 63, neither: 86 }.mcnemar_z();
        assert!((z - 6.959).abs() < 1e-3, "{z}");
    }

    fn ep(success: bool, l: f32, p: f32, stops: Vec<Stop>, final_distance: f32) -> EpisodeResult {
        EpisodeResult {
            program: 0,
            worker: 0,
            env: 0,
            generation: 0,
            steps: 10,
            success,
            collisions: 0,
            num_stops: stops.len() as u32,
            path_length: p,
            shortest_path: l,
            final_distance,
            total_reward: 0.0,
            intervention_steps: 0,
            stops,
        }
    }

    fn stop(success: bool, distance: f32, path_length: f32) -> Stop {
        Stop { step: 1, success, distance, path_length }
    }

    #[test]
    fn a_trajectory_pairs_each_pose_with_the_action_taken_from_it() {
        let rec = |step: u32, start: bool, action: u32, x: f32, end: bool| EnvRecord {
            program: 7,
            episode_step: step,
            episode_start: start as u8,
            last_action: action,
            robot: [x, 0.0, 90.0],
            terminated: end as u8,
            summary: shm_schema::EpisodeSummary { success: end as u32, ..Default::default() },
            ..Default::default()
        };
        let mut t = Trajectory::default();
        // a restarted worker's unfinished episode is forgotten
        assert!(t.record(&rec(0, true, 255, 9.0, false), 0, 1).is_none());
        assert!(t.record(&rec(0, true, 255, 0.0, false), 0, 1).is_none());
        assert!(t.record(&rec(1, false, 0, 0.25, false), 0, 1).is_none());
        let done = t.record(&rec(2, false, 3, 0.25, true), 0, 1).unwrap();
        assert!(done.success && done.program == 7 && done.env == 1);
        let actions: Vec<u8> = done.steps.iter().map(|s| s.action).collect();
        assert_eq!(actions, vec![0, 3, 255]);
        assert_eq!(done.steps[1].x, 0.25);
        assert!(t.steps.is_empty());
    }

    #[test]
    fn spl_of_optimal_double_and_failed_paths() {
        let optimal = ep(true, 3.0, 3.0, vec![stop(true, 0.8, 3.0)], 0.8);
        let double = ep(true, 3.0, 6.0, vec![stop(true, 0.8, 6.0)], 0.8);
        let failed = ep(false, 3.0, 2.0, vec![], 2.5);
        assert_eq!(optimal.at_stops(None).1, 1.0);
        assert_eq!(double.at_stops(None).1, 0.5);
        assert_eq!(failed.at_stops(None), (false, 0.0, 2.5));
        // a path shorter than the geodesic (stopping early inside the region) caps at 1
        assert_eq!(ep(true, 3.0, 2.5, vec![stop(true, 0.9, 2.5)], 0.9).at_stops(None).1, 1.0);
    }

    #[test]
    fn k_stops_count_success_only_by_the_kth_stop() {
        let e = ep(true, 2.0, 4.0, vec![stop(false, 2.4, 1.0), stop(false, 1.6, 2.5), stop(true, 0.7, 4.0)], 0.7);
        assert!(!e.at_stops(Some(1)).0);
        assert!(!e.at_stops(Some(2)).0);
        assert!(e.at_stops(Some(3)).0);
        assert!(e.at_stops(None).0);
        assert_eq!(e.at_stops(Some(3)).1, 0.5);
        // distance where a k-stop episode would have ended
        assert_eq!(e.at_stops(Some(1)).2, 2.4f32 as f64);
        assert_eq!(e.at_stops(Some(2)).2, 1.6f32 as f64);
        // fewer stops than k: the end of the episode
        let once = ep(false, 2.0, 3.0, vec![stop(false, 2.2, 1.0)], 1.9);
        assert_eq!(once.at_stops(Some(3)).2, 1.9f32 as f64);
    }

    #[test]
    fn dts_is_distance_beyond_the_threshold() {
        let near = ep(false, 2.0, 1.0, vec![stop(false, 1.2, 1.0)], 1.2);
        let far = ep(false, 2.0, 1.0, vec![stop(false, 4.0, 1.0)], 4.0);
        let s = scores([&near], Some(1), 1.5);
        assert_eq!(s.dts, 0.0);
        let s = scores([&far], Some(1), 1.5);
        assert!((s.dts - 2.5).abs() < 1e-6);
        let s = scores([&near, &far], Some(1), 1.0);
        assert!((s.dts - (0.2f32 as f64 + 3.0) / 2.0).abs() < 1e-6);
        assert_eq!(s.sr, 0.0);
    }
}
