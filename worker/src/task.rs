//! ObjectNav to a specific instance (§4.2): success, reward, stops, episode end.
//!
//! Success = Stop issued while within `success_distance` (2D) of the target centre *and* with
//! at least `min_visible_pixels` of the target in the frame the robot sees. Several stops are
//! allowed (unlimited in training); the episode ends on success (terminated), when the stop
//! budget is spent (terminated), or at `max_steps` (truncated: bootstrap from the last value).

use serde::{Deserialize, Serialize};

use crate::robot::Action;
use farm::config::TaskConfig;

/// What the environment observed about one step, the task's inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepFacts {
    pub action: Action,
    /// The robot moved (distance travelled = the move step).
    pub moved: bool,
    /// A MoveAhead was blocked.
    pub collided: bool,
    /// Distance travelled this step (metres).
    pub travelled: f32,
    /// 2D distance from the robot to the target centre after the step.
    pub distance: f32,
    /// Pixels of the target instance in the frame the robot saw when acting.
    pub visible_pixels: u32,
    /// Geodesic distance to the success region gained by the step (metres; negative when the
    /// robot moved away), for `progress_reward`.
    pub progress: f32,
}

/// The task's verdict on one step.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct StepResult {
    pub reward: f32,
    pub success: bool,
    /// The episode ended for good (success, or no stops left): no bootstrap.
    pub terminated: bool,
    /// The episode hit the step limit: bootstrap from the value of the final observation.
    pub truncated: bool,
}

impl StepResult {
    pub fn done(&self) -> bool {
        self.terminated || self.truncated
    }
}

/// One stop of an episode, for the metrics at k stops (T4.4).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StopRecord {
    /// Step index (1-based) of the stop.
    pub step: u32,
    pub success: bool,
    /// 2D distance to the target centre when stopping.
    pub distance: f32,
    /// Path length travelled up to this stop.
    pub path_length: f32,
}

/// Running statistics of an episode.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EpisodeStats {
    pub steps: u32,
    pub collisions: u32,
    pub path_length: f32,
    pub success: bool,
    pub stops: Vec<StopRecord>,
    /// Distance to the target centre at the end.
    pub final_distance: f32,
    pub total_reward: f32,
}

/// The task state of one episode.
#[derive(Clone, Debug)]
pub struct Task {
    cfg: TaskConfig,
    pub stats: EpisodeStats,
    done: bool,
}

impl Task {
    pub fn new(cfg: TaskConfig) -> Task {
        Task { cfg, stats: EpisodeStats::default(), done: false }
    }

    pub fn config(&self) -> &TaskConfig {
        &self.cfg
    }

    pub fn reset(&mut self, start_distance: f32) {
        self.stats = EpisodeStats { final_distance: start_distance, ..Default::default() };
        self.done = false;
    }

    pub fn is_done(&self) -> bool {
        self.done
    }

    /// Scores one step. Calling it after the episode ended is a logic error.
    pub fn step(&mut self, f: &StepFacts) -> StepResult {
        assert!(!self.done, "step after the episode ended");
        let c = &self.cfg;
        let s = &mut self.stats;
        s.steps += 1;
        s.path_length += f.travelled;
        s.final_distance = f.distance;
        let mut r = StepResult { reward: -c.step_penalty + c.progress_reward * f.progress, ..Default::default() };
        if f.collided {
            s.collisions += 1;
            r.reward -= c.collision_penalty;
        }
        if f.action == Action::Stop {
            let success = f.distance < c.success_distance && f.visible_pixels >= c.min_visible_pixels;
            s.stops.push(StopRecord { step: s.steps, success, distance: f.distance, path_length: s.path_length });
            if success {
                s.success = true;
                r.success = true;
                r.reward += c.reward_success;
                r.terminated = true;
            } else {
                r.reward -= c.wrong_stop_penalty;
                if c.max_stops > 0 && s.stops.len() as u32 >= c.max_stops {
                    r.terminated = true;
                }
            }
        }
        if !r.terminated && s.steps >= c.max_steps {
            r.truncated = true;
        }
        s.total_reward += r.reward;
        self.done = r.done();
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn facts(action: Action, distance: f32, pixels: u32) -> StepFacts {
        StepFacts {
            action,
            moved: false,
            collided: false,
            travelled: 0.0,
            distance,
            visible_pixels: pixels,
            progress: 0.0,
        }
    }

    #[test]
    fn success_needs_proximity_visibility_and_stop_together() {
        let cfg = TaskConfig::default();
        for (action, d, px, expect) in [
            (Action::Stop, 0.8, 10, true),
            (Action::Stop, 0.8, 1, true),
            (Action::Stop, 1.2, 10, false), // too far
            (Action::Stop, 0.8, 0, false),  // not in view
            (Action::MoveAhead, 0.8, 10, false),
            (Action::RotateLeft, 0.5, 500, false),
        ] {
            let mut t = Task::new(cfg.clone());
            t.reset(3.0);
            let r = t.step(&facts(action, d, px));
            assert_eq!(r.success, expect, "{action:?} at {d} m with {px} px");
            assert_eq!(r.terminated, expect);
        }
    }

    #[test]
    fn rewards_follow_section_4_3_2() {
        let cfg = TaskConfig::default();
        let mut t = Task::new(cfg.clone());
        t.reset(3.0);
        let r = t.step(&facts(Action::MoveAhead, 3.0, 0));
        assert!((r.reward + 0.001).abs() < 1e-7);
        let r = t.step(&StepFacts { collided: true, ..facts(Action::MoveAhead, 3.0, 0) });
        assert!((r.reward + 0.006).abs() < 1e-7);
        let r = t.step(&facts(Action::Stop, 3.0, 0));
        assert!((r.reward + 0.011).abs() < 1e-7);
        assert!(!r.done(), "training allows more stops");
        let r = t.step(&facts(Action::Stop, 0.5, 3));
        assert!((r.reward - 0.999).abs() < 1e-6);
        assert!(r.terminated && !r.truncated);
        assert_eq!(t.stats.stops.len(), 2);
        assert_eq!(t.stats.collisions, 1);
    }

    #[test]
    fn progress_reward_is_off_by_default_and_follows_geodesic_progress() {
        let mut t = Task::new(TaskConfig::default());
        t.reset(3.0);
        let r = t.step(&StepFacts { progress: 0.25, ..facts(Action::MoveAhead, 2.8, 0) });
        assert!((r.reward + 0.001).abs() < 1e-7);
        let mut t = Task::new(TaskConfig { progress_reward: 0.4, ..Default::default() });
        t.reset(3.0);
        let r = t.step(&StepFacts { progress: 0.25, ..facts(Action::MoveAhead, 2.8, 0) });
        assert!((r.reward - (0.1 - 0.001)).abs() < 1e-6);
        let r = t.step(&StepFacts { progress: -0.25, ..facts(Action::MoveAhead, 3.0, 0) });
        assert!((r.reward + 0.1 + 0.001).abs() < 1e-6);
    }

    #[test]
    fn step_limit_truncates() {
        let cfg = TaskConfig { max_steps: 5, ..Default::default() };
        let mut t = Task::new(cfg);
        t.reset(3.0);
        for i in 1..=5 {
            let r = t.step(&facts(Action::RotateLeft, 3.0, 0));
            assert_eq!(r.truncated, i == 5);
            assert!(!r.terminated);
        }
        assert!(t.is_done());
    }

    #[test]
    fn stop_budget_terminates() {
        let cfg = TaskConfig { max_stops: 2, ..Default::default() };
        let mut t = Task::new(cfg);
        t.reset(3.0);
        assert!(!t.step(&facts(Action::Stop, 3.0, 0)).done());
        let r = t.step(&facts(Action::Stop, 3.0, 0));
        assert!(r.terminated && !r.success);
    }
}
