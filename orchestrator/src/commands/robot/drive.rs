//! The policy's discrete actions as motion closed on odometry: MoveAhead drives `move_step`
//! metres, a rotation turns `turn_deg`, within speed limits. Each action aims at the pose the
//! last one aimed at, moved by one step, so small errors of the base do not add up over an
//! episode; a move that stops making progress ends (a collision) where the robot stands.

use shm_schema::action;

/// A pose on the floor of the odometry frame: x, y (m), yaw (rad, counter-clockwise).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pose2 {
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
}

/// The motion of one action and the base's limits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    pub move_step: f64,
    pub turn_deg: f64,
    /// Top speeds (m/s, rad/s): LoCoBot's 0.2 and 0.5 by default.
    pub speed: f64,
    pub turn_rate: f64,
    /// A move that gains under 1 mm (or 0.1°) for this long (s) is blocked.
    pub stall: f64,
}

/// Within these of its aim an action has ended.
const DONE_M: f64 = 0.004;
const DONE_RAD: f64 = 0.003;
/// Gains of the proportional control, and the least command that still moves a base.
const GAIN_V: f64 = 2.0;
const GAIN_W: f64 = 3.0;
const MIN_V: f64 = 0.02;
const MIN_W: f64 = 0.04;

/// One action under way.
#[derive(Clone, Copy, Debug)]
struct Under {
    action: u8,
    /// The best remaining distance (m or rad) so far, and when it was reached (s).
    best: f64,
    best_at: f64,
}

/// How an action ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Ended {
    Reached,
    /// The base stopped making progress: the aim is now where it stands.
    Blocked,
}

/// The base's controller.
#[derive(Clone, Debug)]
pub struct Drive {
    limits: Limits,
    /// Where the actions so far aimed.
    aim: Pose2,
    under: Option<Under>,
}

/// `a − b` wrapped to (−π, π].
pub fn wrap(a: f64) -> f64 {
    let w = (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    if w <= -std::f64::consts::PI { w + std::f64::consts::TAU } else { w }
}

impl Drive {
    pub fn new(limits: Limits, at: Pose2) -> Drive {
        Drive { limits, aim: at, under: None }
    }

    /// Aims from where the robot stands (a new episode, or after the base was moved by hand).
    pub fn restart(&mut self, at: Pose2) {
        self.aim = at;
        self.under = None;
    }

    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    pub fn busy(&self) -> bool {
        self.under.is_some()
    }

    /// Starts `a` (Stop starts nothing) at time `t` (s).
    pub fn start(&mut self, a: u8, now: Pose2, t: f64) {
        let turn = self.limits.turn_deg.to_radians();
        match a {
            action::MOVE_AHEAD => {
                self.aim.x += self.limits.move_step * self.aim.yaw.cos();
                self.aim.y += self.limits.move_step * self.aim.yaw.sin();
            }
            action::ROTATE_LEFT => self.aim.yaw = wrap(self.aim.yaw + turn),
            action::ROTATE_RIGHT => self.aim.yaw = wrap(self.aim.yaw - turn),
            _ => return,
        }
        self.under = Some(Under { action: a, best: f64::INFINITY, best_at: t });
        let best = self.remaining(now);
        self.under = Some(Under { action: a, best, best_at: t });
    }

    /// What is left of the action under way (m for a move, rad for a turn).
    fn remaining(&self, now: Pose2) -> f64 {
        match self.under.map(|u| u.action) {
            Some(action::MOVE_AHEAD) => {
                (self.aim.x - now.x) * self.aim.yaw.cos() + (self.aim.y - now.y) * self.aim.yaw.sin()
            }
            Some(_) => wrap(self.aim.yaw - now.yaw).abs(),
            None => 0.0,
        }
    }

    /// The command (m/s, rad/s) at pose `now` and time `t`; the action's end once it has one.
    pub fn command(&mut self, now: Pose2, t: f64) -> Result<(f64, f64), Ended> {
        let Some(mut u) = self.under else { return Err(Ended::Reached) };
        let left = self.remaining(now);
        let reached = match u.action {
            action::MOVE_AHEAD => left < DONE_M,
            _ => left < DONE_RAD,
        };
        if reached {
            self.under = None;
            return Err(Ended::Reached);
        }
        let gain = if u.action == action::MOVE_AHEAD { 0.001 } else { 0.1f64.to_radians() };
        if left < u.best - gain {
            (u.best, u.best_at) = (left, t);
            self.under = Some(u);
        } else if t - u.best_at > self.limits.stall {
            self.under = None;
            self.aim = now;
            return Err(Ended::Blocked);
        }
        let l = &self.limits;
        Ok(match u.action {
            action::MOVE_AHEAD => {
                // steer back onto the line the move aims along
                let toward = (self.aim.y - now.y).atan2(self.aim.x - now.x);
                let off = if left > 0.05 { wrap(toward - now.yaw) } else { wrap(self.aim.yaw - now.yaw) };
                ((GAIN_V * left).clamp(MIN_V, l.speed), (GAIN_W * off).clamp(-l.turn_rate, l.turn_rate))
            }
            _ => {
                let e = wrap(self.aim.yaw - now.yaw);
                (0.0, e.signum() * (GAIN_W * e.abs()).clamp(MIN_W, l.turn_rate))
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const LOCOBOT: Limits = Limits { move_step: 0.25, turn_deg: 15.0, speed: 0.2, turn_rate: 0.5, stall: 1.0 };

    /// A base that follows commands exactly at 30 Hz, a wall at `wall` metres along x.
    fn run(drive: &mut Drive, p: &mut Pose2, t: &mut f64, wall: f64) -> (Ended, u32) {
        let dt = 1.0 / 30.0;
        for tick in 0..3000 {
            match drive.command(*p, *t) {
                Err(e) => return (e, tick),
                Ok((v, w)) => {
                    assert!(v.abs() <= LOCOBOT.speed + 1e-12 && w.abs() <= LOCOBOT.turn_rate + 1e-12);
                    let x = p.x + v * dt * p.yaw.cos();
                    if x < wall {
                        p.x = x;
                        p.y += v * dt * p.yaw.sin();
                    }
                    p.yaw = wrap(p.yaw + w * dt);
                    *t += dt;
                }
            }
        }
        panic!("the action never ended");
    }

    proptest! {
        #[test]
        fn any_sequence_of_actions_ends_where_the_grid_would(actions in prop::collection::vec(0u8..3, 1..40)) {
            let start = Pose2 { x: 1.0, y: -2.0, yaw: 0.3 };
            let (mut p, mut t) = (start, 0.0);
            let mut d = Drive::new(LOCOBOT, start);
            let (mut yaw, mut x, mut y) = (0.3f64, 1.0f64, -2.0f64);
            for a in actions {
                d.start(a, p, t);
                prop_assert_eq!(run(&mut d, &mut p, &mut t, f64::INFINITY).0, Ended::Reached);
                match a {
                    action::MOVE_AHEAD => { x += 0.25 * yaw.cos(); y += 0.25 * yaw.sin(); }
                    action::ROTATE_LEFT => yaw += 15f64.to_radians(),
                    _ => yaw -= 15f64.to_radians(),
                }
            }
            prop_assert!((p.x - x).hypot(p.y - y) < 0.01, "{:?} vs {}, {}", p, x, y);
            prop_assert!(wrap(p.yaw - yaw).abs() < 0.005);
        }
    }

    #[test]
    fn a_move_into_a_wall_ends_blocked_where_the_robot_stands() {
        let mut p = Pose2::default();
        let (mut d, mut t) = (Drive::new(LOCOBOT, p), 0.0);
        d.start(action::MOVE_AHEAD, p, t);
        let (e, _) = run(&mut d, &mut p, &mut t, 0.1);
        assert_eq!(e, Ended::Blocked);
        assert!(p.x < 0.1 && !d.busy());
        // the next move aims from there, not from the old aim
        d.start(action::MOVE_AHEAD, p, t);
        assert!((d.aim.x - (p.x + 0.25)).abs() < 1e-9);
    }

    #[test]
    fn a_turn_takes_the_time_the_turn_rate_allows() {
        let mut p = Pose2::default();
        let (mut d, mut t) = (Drive::new(LOCOBOT, p), 0.0);
        d.start(action::ROTATE_RIGHT, p, t);
        let (e, ticks) = run(&mut d, &mut p, &mut t, f64::INFINITY);
        assert_eq!(e, Ended::Reached);
        assert!((p.yaw + 15f64.to_radians()).abs() < DONE_RAD);
        // 15° at 0.5 rad/s is 0.52 s: 16 ticks, and a few more slowing down
        assert!((16..40).contains(&ticks), "{ticks} ticks");
    }
}
