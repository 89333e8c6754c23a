//! The 20 intervention gestures (§3.3.1): rejective gestures shown while facing whoever the
//! person looks at — waving one or both hands at two speeds, crossed forearms, palm-out stops,
//! head shakes, a dismissive flick, a wagging finger, shooing, folded arms, "whoa" hands,
//! overhead crossing, pushing away and a cutting sweep.
//!
//! Each is choreographed in the person's own frame: arm key poses are given geometrically (wrist
//! position from the shoulder, hand direction, palm direction), solved to muscles once, and
//! played with min-jerk onsets and sinusoidal or flicking repetitions over a natural idle.

use std::sync::OnceLock;

use nalgebra::Vector3;

use super::synth::{
    ArmGoal, FIST, FLAT, HandPose, INDEX_POINT, Idle, OPEN, RELAXED, STANDING, aim_bone, arm_params, clamp_pose,
    envelope, min_jerk, solve_arm,
};
use super::{FPS, FRAMES, Motion};
use crate::humanoid::muscles::idx;
use crate::humanoid::{Bone, Humanoid, MUSCLES, Side};

/// Number of intervention gestures (§3.3.2: "20 different intervention gestures").
pub const INTERVENTIONS: usize = 20;

/// Names of the intervention gestures, by index.
pub const INTERVENTION_NAMES: [&str; INTERVENTIONS] = [
    "wave right hand, slow",
    "wave right hand, fast",
    "wave left hand, slow",
    "wave left hand, fast",
    "wave both hands, slow",
    "wave both hands, fast",
    "crossed forearms (X)",
    "palm-out stop, right hand",
    "palm-out stop, left hand",
    "palm-out stop, both hands",
    "head shake, slow",
    "head shake, fast",
    "dismissive flick",
    "'no' finger wag",
    "shooing with both hands",
    "arms folded across the chest",
    "hands up 'whoa'",
    "arms crossing over the head",
    "pushing away with both palms",
    "cutting sweep of a flat hand",
];

/// Intervention gesture `index` (0..20); the same motion every time.
pub fn intervention(index: usize) -> Motion {
    assert!(index < INTERVENTIONS, "intervention {index} of {INTERVENTIONS}");
    static ALL: OnceLock<Vec<Motion>> = OnceLock::new();
    ALL.get_or_init(|| (0..INTERVENTIONS).map(build).collect())[index].clone()
}

/// An arm key pose given for the right arm in the person's frame, relative to the right
/// shoulder joint: x outwards, y up, z forward. The left arm uses its mirror image.
#[derive(Clone, Copy)]
struct ArmSpec {
    wrist: [f32; 3],
    hand: [f32; 3],
    palm: [f32; 3],
    fingers: &'static HandPose,
}

/// Solved arm muscles (shoulder..hand) and fingers; anatomical, so valid for either side.
#[derive(Clone, Copy)]
struct ArmKey {
    arm: [f32; 9],
    fingers: HandPose,
}

fn solve(spec: ArmSpec) -> ArmKey {
    let sk = Humanoid::standard().skeleton();
    let a = idx::RIGHT_ARM;
    let ua = Bone::RightUpperArm;
    let shoulder = sk.chain(&STANDING, ua).0;
    let v = |a: [f32; 3]| Vector3::from(a);
    let wrist = shoulder + v(spec.wrist);
    let goal = ArmGoal { wrist: Some(wrist), hand_dir: Some(v(spec.hand)), palm: Some(v(spec.palm)), ray: None };
    // Elbow flexion from the shoulder–wrist distance (law of cosines).
    let (l1, l2) = (sk.bone_def(ua).tip.norm(), sk.bone_def(Bone::RightLowerArm).tip.norm());
    let d = v(spec.wrist).norm().clamp((l1 - l2).abs() + 1e-3, l1 + l2 - 1e-3);
    let inner = ((l1 * l1 + l2 * l2 - d * d) / (2.0 * l1 * l2)).clamp(-1.0, 1.0).acos().to_degrees();
    let stretch = ((80.0 - (180.0 - inner)) / 80.0).clamp(-1.0, 1.0);
    let stay = [0.05, 0.05, 0.01, 0.01, 0.01, 0.01, 0.01, 0.02, 0.02];
    let cost = |pose: &[f32; MUSCLES]| {
        let (p, q) = sk.chain(pose, Bone::RightHand);
        let hand = q * sk.bone_def(Bone::RightHand).tip.normalize();
        let palm = q * -Vector3::y();
        16.0 * (p - wrist).norm_squared()
            + (hand - v(spec.hand).normalize()).norm_squared()
            + 0.5 * (palm - v(spec.palm).normalize()).norm_squared()
    };
    // Several starts (upper-arm and forearm twist) so that no start gets stuck at a limit.
    let mut best = (f32::INFINITY, STANDING);
    for twist in [-0.6f32, 0.0, 0.5, 1.0] {
        for fore in [-0.8f32, 0.0, 0.8] {
            let mut pose = STANDING;
            pose[a + idx::ARM_TWIST] = twist;
            pose[a + idx::FOREARM_TWIST] = fore;
            pose[a + idx::FOREARM_STRETCH] = stretch;
            aim_bone(sk, &mut pose, ua, wrist - shoulder);
            solve_arm(sk, &mut pose, Side::Right, &goal, &arm_params(Side::Right), &stay, 40);
            let c = cost(&pose);
            if c < best.0 {
                best = (c, pose);
            }
        }
    }
    let pose = best.1;
    ArmKey { arm: std::array::from_fn(|k| pose[a + k]), fingers: *spec.fingers }
}

fn write_arm(pose: &mut [f32; MUSCLES], side: Side, key: &ArmKey, w: f32) {
    let a = side.arm_muscles();
    for k in 0..9 {
        pose[a + k] += (key.arm[k] - pose[a + k]) * w;
    }
    let f = side.finger_muscles();
    for k in 0..20 {
        pose[f + k] += (key.fingers[k] - pose[f + k]) * w;
    }
}

/// How a repeated movement goes between its two key poses.
#[derive(Clone, Copy)]
enum Beat {
    /// Holds the first key pose.
    Hold,
    /// Swings smoothly between the keys at this rate (Hz).
    Sine(f32),
    /// Snaps quickly to the second key and drifts back, at this rate (Hz).
    Flick(f32),
}

impl Beat {
    /// Blend factor from the first key (0) to the second (1) at `frame`.
    fn at(self, frame: f32) -> f32 {
        match self {
            Beat::Hold => 0.0,
            Beat::Sine(hz) => 0.5 - 0.5 * (std::f32::consts::TAU * hz * frame / FPS).cos(),
            Beat::Flick(hz) => {
                let phase = (hz * frame / FPS).fract();
                if phase < 0.25 { min_jerk(phase / 0.25) } else { 1.0 - min_jerk((phase - 0.25) / 0.75) }
            }
        }
    }
}

/// One part of a gesture: which arms, their two keys, the beat, and when it is active.
struct Act {
    sides: &'static [Side],
    a: ArmKey,
    b: ArmKey,
    beat: Beat,
    /// Rise start, rise length, fall start, fall length (frames).
    span: [f32; 4],
}

/// A head shake: amplitude of the turn (muscle units) and rate.
struct Shake {
    amp: f32,
    hz: f32,
    span: [f32; 4],
}

fn spec(wrist: [f32; 3], hand: [f32; 3], palm: [f32; 3], fingers: &'static HandPose) -> ArmKey {
    solve(ArmSpec { wrist, hand, palm, fingers })
}

const RIGHT: &[Side] = &[Side::Right];
const LEFT: &[Side] = &[Side::Left];
const BOTH: &[Side] = &[Side::Left, Side::Right];

fn build(index: usize) -> Motion {
    let (acts, shakes) = choreography(index);
    animate(&acts, &shakes)
}

/// Gesture `index`'s arm movements and head shakes: one arm of the match per gesture.
fn choreography(index: usize) -> (Vec<Act>, Vec<Shake>) {
    let fwd = [0.0, 0.0, 1.0];
    let up = [0.0, 1.0, 0.0];
    let down = [0.0, -1.0, 0.0];
    // Waving: the forearm upright beside the head, palm forward, swaying out and in.
    let wave_out = spec([0.3, 0.17, 0.17], [0.55, 0.84, 0.0], fwd, &OPEN);
    let wave_in = spec([0.12, 0.19, 0.2], [-0.35, 0.94, 0.0], fwd, &OPEN);
    // Palm-out stop: arm straight ahead at shoulder height, hand up, palm forward.
    let stop = spec([0.0, -0.03, 0.49], [0.0, 1.0, 0.15], fwd, &FLAT);
    let stop_push = spec([0.0, -0.02, 0.52], [0.0, 1.0, 0.25], fwd, &FLAT);
    let span = |a: f32, b: f32| [a, 12.0, b, 12.0];
    match index {
        0 => {
            (vec![Act { sides: RIGHT, a: wave_in, b: wave_out, beat: Beat::Sine(1.3), span: span(10.0, 80.0) }], vec![])
        }
        1 => {
            (vec![Act { sides: RIGHT, a: wave_in, b: wave_out, beat: Beat::Sine(2.8), span: span(8.0, 78.0) }], vec![])
        }
        2 => {
            (vec![Act { sides: LEFT, a: wave_in, b: wave_out, beat: Beat::Sine(1.3), span: span(10.0, 80.0) }], vec![])
        }
        3 => (vec![Act { sides: LEFT, a: wave_in, b: wave_out, beat: Beat::Sine(2.8), span: span(8.0, 78.0) }], vec![]),
        4 => {
            (vec![Act { sides: BOTH, a: wave_in, b: wave_out, beat: Beat::Sine(1.1), span: span(10.0, 80.0) }], vec![])
        }
        5 => (vec![Act { sides: BOTH, a: wave_in, b: wave_out, beat: Beat::Sine(2.5), span: span(8.0, 78.0) }], vec![]),
        6 => {
            // Forearms crossed in an X in front of the chest, fists, pressed forward twice.
            let x = spec([-0.27, -0.04, 0.33], [-0.55, 0.8, 0.15], fwd, &FIST);
            let x2 = spec([-0.27, -0.02, 0.38], [-0.55, 0.8, 0.15], fwd, &FIST);
            (vec![Act { sides: BOTH, a: x, b: x2, beat: Beat::Flick(0.9), span: span(12.0, 78.0) }], vec![])
        }
        7 => {
            (vec![Act { sides: RIGHT, a: stop, b: stop_push, beat: Beat::Flick(0.8), span: span(10.0, 80.0) }], vec![])
        }
        8 => (vec![Act { sides: LEFT, a: stop, b: stop_push, beat: Beat::Flick(0.8), span: span(10.0, 80.0) }], vec![]),
        9 => (vec![Act { sides: BOTH, a: stop, b: stop_push, beat: Beat::Flick(0.8), span: span(10.0, 80.0) }], vec![]),
        10 => (vec![], vec![Shake { amp: 0.6, hz: 1.2, span: span(10.0, 82.0) }]),
        11 => (vec![], vec![Shake { amp: 0.45, hz: 2.6, span: span(10.0, 80.0) }]),
        12 => {
            // Back of the hand flicks the robot away: from in front of the belly out to the side.
            let inside = spec([-0.12, -0.32, 0.3], [-0.3, 0.1, 0.95], [0.0, 0.6, -0.8], &RELAXED);
            let out = spec([0.3, -0.25, 0.33], [0.85, 0.25, 0.45], [0.5, -0.3, 0.8], &OPEN);
            (vec![Act { sides: RIGHT, a: inside, b: out, beat: Beat::Flick(1.1), span: span(12.0, 76.0) }], vec![])
        }
        13 => {
            // Index finger up in front of the shoulder, wagging side to side; the head shakes along.
            let l = spec([0.02, 0.04, 0.32], [-0.45, 0.89, 0.05], fwd, &INDEX_POINT);
            let r = spec([0.08, 0.04, 0.32], [0.45, 0.89, 0.05], fwd, &INDEX_POINT);
            (
                vec![Act { sides: RIGHT, a: l, b: r, beat: Beat::Sine(2.4), span: span(10.0, 80.0) }],
                vec![Shake { amp: 0.15, hz: 1.2, span: span(14.0, 76.0) }],
            )
        }
        14 => {
            // Shooing: both hands low in front, palms down, flapping forward from the wrists.
            let a = spec([-0.03, -0.36, 0.3], fwd, down, &OPEN);
            let b = spec([-0.02, -0.33, 0.36], [0.0, 0.75, 0.66], [0.0, -0.66, 0.75], &OPEN);
            (vec![Act { sides: BOTH, a, b, beat: Beat::Sine(2.2), span: span(10.0, 80.0) }], vec![])
        }
        15 => {
            // Arms folded across the chest, head shaking slowly.
            let fold = spec([-0.3, -0.24, 0.22], [-0.95, 0.15, -0.25], [0.0, -0.3, -0.95], &RELAXED);
            (
                vec![Act { sides: BOTH, a: fold, b: fold, beat: Beat::Hold, span: [10.0, 16.0, 80.0, 14.0] }],
                vec![Shake { amp: 0.3, hz: 1.0, span: span(30.0, 76.0) }],
            )
        }
        16 => {
            // Both hands up beside the head, palms forward, pushed out a little.
            let a = spec([0.2, 0.05, 0.2], up, fwd, &OPEN);
            let b = spec([0.21, 0.04, 0.27], [0.0, 0.97, 0.25], fwd, &OPEN);
            (vec![Act { sides: BOTH, a, b, beat: Beat::Sine(1.6), span: span(10.0, 80.0) }], vec![])
        }
        17 => {
            // Both arms swung up and crossed over the head, again and again.
            let open = spec([0.2, 0.5, 0.12], [0.35, 0.94, 0.0], fwd, &OPEN);
            let cross = spec([-0.18, 0.52, 0.16], [-0.4, 0.92, 0.0], fwd, &OPEN);
            (vec![Act { sides: BOTH, a: open, b: cross, beat: Beat::Sine(1.0), span: span(10.0, 80.0) }], vec![])
        }
        18 => {
            // Pushing the air away with both palms, arms extending forward.
            let near = spec([-0.02, -0.1, 0.24], [0.0, 0.95, 0.3], fwd, &FLAT);
            let far = spec([-0.02, -0.07, 0.48], [0.0, 0.95, 0.3], fwd, &FLAT);
            (vec![Act { sides: BOTH, a: near, b: far, beat: Beat::Flick(1.2), span: span(10.0, 80.0) }], vec![])
        }
        19 => {
            // A flat hand, palm down, sweeping sideways in front of the chest: "cut it".
            let left = spec([-0.22, -0.15, 0.36], [-0.2, 0.0, 0.98], down, &FLAT);
            let right = spec([0.27, -0.15, 0.34], [0.3, 0.0, 0.95], down, &FLAT);
            (vec![Act { sides: RIGHT, a: left, b: right, beat: Beat::Sine(1.8), span: span(10.0, 80.0) }], vec![])
        }
        _ => unreachable!("checked by the caller"),
    }
}

/// The motion: each act's arms blend between its two keys on its beat within its envelope,
/// each shake turns the neck and head; the idle sway on top.
fn animate(acts: &[Act], shakes: &[Shake]) -> Motion {
    let idle = Idle::fixed();
    let mut motion = Motion::constant(&STANDING);
    for t in 0..FRAMES {
        let x = t as f32;
        let m = motion.frame_mut(t);
        for act in acts {
            let [a, rise, b, fall] = act.span;
            let e = envelope(x, a, rise, b, fall);
            if e <= 0.0 {
                continue;
            }
            // Beats start at the pose the arm rose to.
            let s = act.beat.at((x - a - rise).max(0.0));
            let mut key = act.a;
            for k in 0..9 {
                key.arm[k] += (act.b.arm[k] - act.a.arm[k]) * s;
            }
            for k in 0..20 {
                key.fingers[k] += (act.b.fingers[k] - act.a.fingers[k]) * s;
            }
            for &side in act.sides {
                write_arm(m, side, &key, e);
            }
        }
        for sh in shakes {
            let [a, rise, b, fall] = sh.span;
            let e = envelope(x, a, rise, b, fall);
            let turn = sh.amp * e * (std::f32::consts::TAU * sh.hz * (x - a) / FPS).sin();
            m[idx::NECK_TURN] += 0.5 * turn;
            m[idx::HEAD_TURN] += 0.5 * turn;
        }
        idle.apply(m, x);
        clamp_pose(m);
    }
    motion
}

#[cfg(test)]
mod tests {
    use nalgebra::Point3;

    use super::*;

    fn solved(spec: ArmSpec) -> (ArmKey, f32) {
        let key = solve(spec);
        let h = Humanoid::default();
        let mut pose = STANDING;
        write_arm(&mut pose, Side::Right, &key, 1.0);
        let sk = h.skeleton();
        let shoulder = sk.chain(&STANDING, Bone::RightUpperArm).0;
        let wrist = sk.chain(&pose, Bone::RightHand).0;
        (key, (wrist - (shoulder + Vector3::from(spec.wrist))).norm())
    }

    #[test]
    fn all_twenty_are_distinct_valid_and_fixed() {
        let all: Vec<Motion> = (0..INTERVENTIONS).map(intervention).collect();
        for (i, m) in all.iter().enumerate() {
            assert!(m.as_flat().iter().all(|v| v.is_finite() && v.abs() <= 1.0), "{}", INTERVENTION_NAMES[i]);
            assert_eq!(*m, intervention(i));
            // Starts and ends standing.
            for t in [0, FRAMES - 1] {
                let d: f32 = m.frame(t).iter().zip(&STANDING).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                assert!(d < 0.1, "{} frame {t} differs from standing by {d}", INTERVENTION_NAMES[i]);
            }
            for (j, n) in all.iter().enumerate().skip(i + 1) {
                let diff: f32 =
                    m.as_flat().iter().zip(n.as_flat()).map(|(a, b)| (a - b).abs()).sum::<f32>() / FRAMES as f32;
                assert!(diff > 0.3, "{} and {} are too alike ({diff})", INTERVENTION_NAMES[i], INTERVENTION_NAMES[j]);
            }
        }
    }

    #[test]
    fn key_poses_reach_their_wrist_goals() {
        for s in [
            ArmSpec { wrist: [0.3, 0.17, 0.17], hand: [0.55, 0.84, 0.0], palm: [0.0, 0.0, 1.0], fingers: &OPEN },
            ArmSpec { wrist: [0.0, -0.03, 0.49], hand: [0.0, 1.0, 0.15], palm: [0.0, 0.0, 1.0], fingers: &FLAT },
            ArmSpec {
                wrist: [-0.3, -0.24, 0.22],
                hand: [-0.95, 0.15, -0.25],
                palm: [0.0, -0.3, -0.95],
                fingers: &RELAXED,
            },
        ] {
            let (_, err) = solved(s);
            assert!(err < 0.03, "wrist {err} m off");
        }
    }

    /// Hands go where the names say: waving hands above the shoulder and moving sideways, the
    /// stop palm in front facing forward, the head shake turning the face both ways.
    #[test]
    fn gestures_look_like_their_names() {
        let h = Humanoid::default();
        let at = |m: &Motion, t: usize| h.pose(m.frame(t), Point3::origin(), 0.0);
        let wave = intervention(1);
        let xs: Vec<f32> = (30..60).map(|t| at(&wave, t).hand_position(Side::Right).x).collect();
        let span = xs.iter().cloned().fold(f32::MIN, f32::max) - xs.iter().cloned().fold(f32::MAX, f32::min);
        assert!(span > 0.08, "the waving hand sweeps {span} m");
        assert!(at(&wave, 40).hand_position(Side::Right).y > at(&wave, 40).position(Bone::RightUpperArm).y);
        let left = intervention(2);
        assert!(at(&left, 40).hand_position(Side::Left).y > 1.4 && at(&left, 40).hand_position(Side::Right).y < 1.0);

        let stop = intervention(9);
        let p = at(&stop, 45);
        for side in Side::BOTH {
            assert!(p.palm_normal(side).z > 0.7, "{side:?} palm faces forward: {:?}", p.palm_normal(side));
            assert!(p.hand_position(side).z > 0.4);
        }
        let shake = intervention(11);
        let turns: Vec<f32> = (20..70).map(|t| at(&shake, t).head_forward().x).collect();
        assert!(turns.iter().any(|&x| x > 0.3) && turns.iter().any(|&x| x < -0.3));
        let folded = at(&intervention(15), 50);
        assert!(
            folded.hand_position(Side::Right).x < 0.0 && folded.hand_position(Side::Left).x > 0.0,
            "hands at the opposite elbows"
        );
    }
}
