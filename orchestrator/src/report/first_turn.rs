//! Which way a policy turns first, by the side the target is on: the first use a referencing
//! gesture has; and where it heads when it first moves ahead, which a policy that always turns
//! the same way may still take from the gesture (it stops turning facing the target). Counted
//! over the episodes whose target is out of view at the start (more than half the field of view
//! off the heading).

use std::fmt::Write;

use farm::metrics::Trajectory;
use worker::geometry::{angle_diff_deg, yaw_of};
use worker::program::Program;
use worker::robot::{Action, RobotPose};

/// Counts of first turns (right, all) for targets on the robot's left and on its right.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FirstTurns {
    pub left: (usize, usize),
    pub right: (usize, usize),
    /// Out-of-view episodes whose first move was ahead (or that never moved).
    pub no_turn: usize,
}

/// The target's bearing from the robot's start (degrees, + to the right).
pub fn start_bearing(p: &Program) -> f32 {
    bearing(p, &p.robot_start())
}

/// The start bearing of a program whose target is out of view at the start (more than half the
/// field of view off the heading); `None` where it is in view.
fn out_of_view_at_start(p: &Program, half_fov: f32) -> Option<f32> {
    let b = start_bearing(p);
    (b.abs() > half_fov).then_some(b)
}

/// The target's bearing from a robot at `pose` (degrees, + to the right).
fn bearing(p: &Program, pose: &RobotPose) -> f32 {
    let t = p.target_center();
    angle_diff_deg(pose.yaw, yaw_of(nalgebra::Vector2::new(t.x, t.z) - pose.xz().coords))
}

/// Where a policy heads at its first move ahead, over the episodes whose target is out of view
/// at the start.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FirstHeading {
    pub out_of_view: usize,
    /// |the target's bearing| at each first move ahead (degrees), ascending.
    pub errors: Vec<f32>,
    /// Half the field of view: a heading within it has the target in view.
    pub half_fov: f32,
}

impl FirstHeading {
    /// `programs`: the split the trajectories ran on, indexed by their program.
    pub fn of(trajectories: &[Trajectory], programs: &[Program], fov_deg: f32) -> FirstHeading {
        let mut h = FirstHeading { half_fov: fov_deg / 2.0, ..FirstHeading::default() };
        for t in trajectories {
            let p = &programs[t.program as usize];
            if out_of_view_at_start(p, h.half_fov).is_none() {
                continue;
            }
            h.out_of_view += 1;
            if let Some(s) = t.steps.iter().find(|s| s.action == Action::MoveAhead as u8) {
                h.errors.push(bearing(p, &RobotPose { x: s.x, z: s.z, yaw: s.yaw }).abs());
            }
        }
        h.errors.sort_by(f32::total_cmp);
        h
    }

    /// Share of first moves ahead with the target within half the field of view.
    pub fn in_view(&self) -> f64 {
        self.errors.iter().filter(|&&e| e <= self.half_fov).count() as f64 / self.errors.len().max(1) as f64
    }

    pub fn median(&self) -> Option<f32> {
        self.errors.get(self.errors.len() / 2).copied()
    }

    /// One row per (evaluation, pass).
    pub fn markdown(rows: &[(String, &str, FirstHeading)]) -> String {
        let mut md = String::from("\n## The first move ahead: where the policy heads\n\n");
        md += "Episodes whose target is outside the field of view at the start: the target's bearing from the \
               robot when it first moves ahead. A policy that turns the same way first whichever side the \
               target is on can still stop turning when it faces the target; what it takes from a gesture \
               for that, it loses with another room's.\n\n";
        md += "| evaluation | pass | out of view at the start | moved ahead | target in view at the first move ahead | median \\|bearing\\| |\n|---|---|---:|---:|---:|---:|\n";
        for (label, pass, h) in rows {
            let median = h.median().map_or("-".to_string(), |m| format!("{m:.0}°"));
            writeln!(
                md,
                "| {label} | {pass} | {} | {} | {:.1}% | {median} |",
                h.out_of_view,
                h.errors.len(),
                100.0 * h.in_view()
            )
            .unwrap();
        }
        md
    }
}

impl FirstTurns {
    /// `programs`: the split the trajectories ran on, indexed by their program.
    pub fn of(trajectories: &[Trajectory], programs: &[Program], fov_deg: f32) -> FirstTurns {
        let mut f = FirstTurns::default();
        for t in trajectories {
            let Some(bearing) = out_of_view_at_start(&programs[t.program as usize], fov_deg / 2.0) else {
                continue;
            };
            let first = t.steps.iter().map(|s| s.action).find(|&a| a != Action::Stop as u8 && a <= Action::Stop as u8);
            let side = if bearing > 0.0 { &mut f.right } else { &mut f.left };
            match first {
                Some(a) if a == Action::RotateRight as u8 => *side = (side.0 + 1, side.1 + 1),
                Some(a) if a == Action::RotateLeft as u8 => side.1 += 1,
                _ => f.no_turn += 1,
            }
        }
        f
    }

    /// Share of first turns toward the target.
    pub fn toward(&self) -> f64 {
        let toward = self.right.0 + (self.left.1 - self.left.0);
        toward as f64 / (self.left.1 + self.right.1).max(1) as f64
    }

    pub fn markdown(&self) -> String {
        let pct = |(k, n): (usize, usize)| 100.0 * k as f64 / n.max(1) as f64;
        let mut md = String::from("\n## The first turn: which way the policy turns when the target is out of view\n\n");
        md += "Episodes whose target is outside the field of view at the start and whose first move is a turn.\n\n";
        md += "| target on the left: turns right first | target on the right: turns right first | first turn toward the target | first move ahead |\n|---:|---:|---:|---:|\n";
        writeln!(
            md,
            "| {:.1}% of {} | {:.1}% of {} | {:.1}% | {} |",
            pct(self.left),
            self.left.1,
            pct(self.right),
            self.right.1,
            100.0 * self.toward(),
            self.no_turn
        )
        .unwrap();
        md
    }
}

#[cfg(test)]
mod tests {
    use farm::metrics::TrajectoryStep;

    use super::*;

    fn program(yaw: f32, target: [f32; 3]) -> Program {
        serde_json::from_value(serde_json::json!({
            "id": 0, "scene": "FloorPlan1", "scene_type": "Kitchen", "target": "Bread", "target_object": 0,
            "target_pos": target, "instances": 1, "human_pos": [1.0, 0.0, 1.0], "human_yaw": 0.0,
            "robot_pos": [0.0, 0.0, 0.0], "robot_yaw": yaw, "geodesic": 1.0, "target_geodesic": 1.0,
            "starts_successful": false, "robot_human_distance": 1.4, "gesture_accuracy": 1.0, "hand": "Right",
            "style": 0, "seed": 1
        }))
        .expect("a program")
    }

    fn trajectory(program: u64, actions: &[Action]) -> Trajectory {
        let step =
            |a: &Action| TrajectoryStep { x: 0.0, z: 0.0, yaw: 0.0, action: *a as u8, gesture: 1, intervention: 0 };
        Trajectory { program, steps: actions.iter().map(step).collect(), ..Trajectory::default() }
    }

    /// Yaw is clockwise from above: facing +z, +x is on the right. Stops before the first move
    /// are skipped; targets in view are not counted.
    #[test]
    fn turns_are_counted_by_the_targets_side() {
        let programs = [
            program(0.0, [2.0, 0.5, 0.0]),  // right
            program(0.0, [-2.0, 0.5, 0.0]), // left
            program(90.0, [0.0, 0.5, 2.0]), // facing +x, +z is on the left
            program(0.0, [0.0, 0.5, 2.0]),  // ahead: in view
            program(0.0, [0.5, 0.5, -2.0]), // behind, a little right
        ];
        assert!((start_bearing(&programs[0]) - 90.0).abs() < 1e-3 && (start_bearing(&programs[2]) + 90.0).abs() < 1e-3);
        let (l, r, s, m) = (Action::RotateLeft, Action::RotateRight, Action::Stop, Action::MoveAhead);
        let trajs = [
            trajectory(0, &[s, r, m]),
            trajectory(1, &[l, l]),
            trajectory(2, &[r]),
            trajectory(3, &[l]),
            trajectory(4, &[m, r]),
        ];
        let f = FirstTurns::of(&trajs, &programs, 90.0);
        assert_eq!(f, FirstTurns { left: (1, 2), right: (1, 1), no_turn: 1 });
        assert!((f.toward() - 2.0 / 3.0).abs() < 1e-9);
        assert!(f.markdown().contains("| 50.0% of 2 | 100.0% of 1 | 66.7% | 1 |"), "{}", f.markdown());
    }

    /// The bearing is read where the robot stands and faces at its first move ahead: turned to
    /// face the target, then moved (in view); moved at once away from it (behind); never moved.
    #[test]
    fn the_first_move_ahead_is_scored_by_the_bearing_then() {
        let programs = [program(0.0, [2.0, 0.5, 0.0]), program(0.0, [0.0, 0.5, -2.0]), program(0.0, [-2.0, 0.5, 0.0])];
        let at = |x: f32, yaw: f32, a: Action| TrajectoryStep {
            x,
            z: 0.0,
            yaw,
            action: a as u8,
            gesture: 1,
            intervention: 0,
        };
        let (r, m, s) = (Action::RotateRight, Action::MoveAhead, Action::Stop);
        let trajs = [
            // turned to face +x, then moves: the target straight ahead
            Trajectory {
                program: 0,
                steps: vec![at(0.0, 0.0, r), at(0.0, 90.0, m), at(0.25, 90.0, s)],
                ..Trajectory::default()
            },
            Trajectory { program: 1, steps: vec![at(0.0, 0.0, m)], ..Trajectory::default() },
            Trajectory { program: 2, steps: vec![at(0.0, 0.0, s)], ..Trajectory::default() },
        ];
        let h = FirstHeading::of(&trajs, &programs, 90.0);
        assert_eq!((h.out_of_view, h.errors.len()), (3, 2));
        assert!(h.errors[0] < 1e-3 && (h.errors[1] - 180.0).abs() < 1e-3, "{:?}", h.errors);
        assert_eq!(h.in_view(), 0.5);
        let md = FirstHeading::markdown(&[("+Both".into(), "normal", h)]);
        assert!(md.contains("| +Both | normal | 3 | 2 | 50.0% | 180° |"), "{md}");
    }
}
