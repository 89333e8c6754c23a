//! A person's own gesture, filmed by a camera in place of the recorder's Kinect and Leap Motion
//! (§3.2.3): body and hand landmarks of every video frame (MediaPipe Holistic; `orchestrator
//! gesture capture` runs it) → the 95 muscles of our skeleton by inverse kinematics → trimmed to
//! the gesture and set into the dataset's 100 frames at 30 fps.
//!
//! Landmarks are read in the person's own hips frame (right along the hips, up towards the
//! shoulders), so where the person stands in the picture and which way they face the camera do
//! not matter. Per frame: the three spine twists (equal shares) to the turn of the shoulders over
//! the hips; each arm's nine muscles (Levenberg–Marquardt, warm-started from the frame before) to
//! the directions of the upper arm, the forearm and, where the hand is seen, the hand and its
//! palm; each hand's 20 finger muscles to its knuckles' flexion and spread (in the palm's frame)
//! and its other joints' bends; neck and head to the face's turn and nod (against its resting
//! nod). Legs and the rest stay at rest.

use std::fmt;

use nalgebra::{Matrix3, Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::synth::{RELAXED, STANDING, arm_params, least_squares};
use super::{FPS, FRAMES, Motion};
use crate::humanoid::muscles::idx;
use crate::humanoid::{Bone, Finger, MUSCLES, Side, Skeleton, SkeletonPose};

/// Landmarks per body (MediaPipe Pose) and per hand (MediaPipe Hands).
pub const POSE_LANDMARKS: usize = 33;
pub const HAND_LANDMARKS: usize = 21;

// MediaPipe Pose's landmark numbers (the person's own left and right).
const NOSE: usize = 0;
const LEFT_EAR: usize = 7;
const RIGHT_EAR: usize = 8;
const LEFT_SHOULDER: usize = 11;
const RIGHT_SHOULDER: usize = 12;
const LEFT_ELBOW: usize = 13;
const RIGHT_ELBOW: usize = 14;
const LEFT_WRIST: usize = 15;
const RIGHT_WRIST: usize = 16;
const LEFT_HIP: usize = 23;
const RIGHT_HIP: usize = 24;

/// MediaPipe Hands' landmarks of each digit from the wrist (0) to its tip, in `Finger` order.
const DIGITS: [[usize; 5]; 5] =
    [[0, 1, 2, 3, 4], [0, 5, 6, 7, 8], [0, 9, 10, 11, 12], [0, 13, 14, 15, 16], [0, 17, 18, 19, 20]];
const INDEX_MCP: usize = 5;
const MIDDLE_MCP: usize = 9;
const LITTLE_MCP: usize = 17;

/// Below this visibility a pose landmark is taken as not seen.
const VISIBLE: f32 = 0.5;

/// One video frame's landmarks, as the landmark script writes them (one JSON object a line).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LandmarkFrame {
    /// Seconds from the video's start.
    pub t: f32,
    /// The 33 pose world landmarks: x right, y down, z away from the camera (metres, origin
    /// between the hips), and visibility.
    pub pose: Option<Vec<[f32; 4]>>,
    /// The 21 landmarks of the person's own left and right hand: x and y in pixels, z (depth)
    /// at x's scale; only their directions are used.
    pub left_hand: Option<Vec<[f32; 3]>>,
    pub right_hand: Option<Vec<[f32; 3]>>,
    /// The 33 pose landmarks in the image (pixels): where the person is in the frame.
    #[serde(default)]
    pub pose_image: Option<Vec<[f32; 2]>>,
}

impl LandmarkFrame {
    fn hand(&self, side: Side) -> Option<&[[f32; 3]]> {
        match side {
            Side::Left => self.left_hand.as_deref(),
            Side::Right => self.right_hand.as_deref(),
        }
        .filter(|h| h.len() == HAND_LANDMARKS)
    }

    fn pose(&self) -> Option<&[[f32; 4]]> {
        self.pose.as_deref().filter(|p| p.len() == POSE_LANDMARKS)
    }
}

/// Why a video gives no gesture: one line, without the file (the caller names it).
#[derive(Clone, Debug, PartialEq)]
pub enum CaptureError {
    TooShort { frames: usize, seconds: f32 },
    NoPerson { missing: usize, frames: usize },
    NoGesture,
    HandsLost { side: Side, lost: usize, frames: usize },
}

impl fmt::Display for CaptureError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CaptureError::TooShort { frames, seconds } => {
                write!(f, "{frames} frames ({seconds:.1} s): too short; a gesture needs at least {MIN_SECONDS} s")
            }
            CaptureError::NoPerson { missing, frames } => write!(
                f,
                "no person found in {missing} of {frames} frames (a whole upper body, hips to head, must be in view)"
            ),
            CaptureError::NoGesture => write!(f, "no arm moved away from rest: no gesture found"),
            CaptureError::HandsLost { side, lost, frames } => write!(
                f,
                "the {} hand was lost in {lost} of the gesture's {frames} frames (its fingers need it; keep the hand in \
                 view, or pass --hands-optional for a relaxed hand)",
                side_name(*side)
            ),
        }
    }
}

impl std::error::Error for CaptureError {}

fn side_name(s: Side) -> &'static str {
    match s {
        Side::Left => "left",
        Side::Right => "right",
    }
}

/// The shortest video a gesture is looked for in.
pub const MIN_SECONDS: f32 = 1.0;

/// What a video gave.
#[derive(Clone, Debug)]
pub struct Capture {
    /// Muscles of every video frame (a frame without a person holds the one before).
    pub frames: Vec<[f32; MUSCLES]>,
    /// Each frame's time (s).
    pub times: Vec<f32>,
    /// The arm that moved most: the gesturing one.
    pub side: Side,
    /// First and last video frame of the gesture, with its lead-in and return.
    pub span: (usize, usize),
    /// The gesture in the dataset's 100 frames at 30 fps.
    pub motion: Motion,
    /// Frames with a person; frames of the gesture where the gesturing hand was seen.
    pub person_frames: usize,
    pub hand_frames: (usize, usize),
}

/// Options of a capture.
#[derive(Clone, Copy, Debug, Default)]
pub struct CaptureOptions {
    /// A gesture whose hand is lost in most frames keeps a relaxed hand instead of failing.
    pub hands_optional: bool,
}

/// The hips frame: rows are the person's right, up and forward in the landmarks' axes.
/// The camera's axes are right-handed; ours name a person's right, up and front, so forward is
/// up × right there (and right × up in the skeleton's axes).
fn hips_frame(right: Vector3<f32>, up: Vector3<f32>, right_handed: bool) -> Option<Matrix3<f32>> {
    let r = right.try_normalize(1e-6)?;
    let u = (up - r * up.dot(&r)).try_normalize(1e-6)?;
    let f = if right_handed { u.cross(&r) } else { r.cross(&u) };
    Some(Matrix3::from_rows(&[r.transpose(), u.transpose(), f.transpose()]))
}

fn v3(p: [f32; 4]) -> Vector3<f32> {
    Vector3::new(p[0], p[1], p[2])
}

/// Directions of one frame's landmarks in the hips frame (x right, y up, z forward).
struct Observed {
    /// Shoulder line, right minus left.
    shoulders: Vector3<f32>,
    /// Per side: upper arm, forearm (None when the elbow or wrist is not seen).
    arms: [Option<(Vector3<f32>, Vector3<f32>)>; 2],
    /// Per side: the hand's landmarks relative to its wrist.
    hands: [Option<[Vector3<f32>; HAND_LANDMARKS]>; 2],
    /// Nose minus the ears' middle.
    face: Option<Vector3<f32>>,
}

fn observe(f: &LandmarkFrame) -> Option<Observed> {
    let p = f.pose()?;
    let seen = |i: usize| p[i][3] >= VISIBLE;
    if ![LEFT_SHOULDER, RIGHT_SHOULDER, LEFT_HIP, RIGHT_HIP].into_iter().all(seen) {
        return None;
    }
    let hips = (v3(p[LEFT_HIP]) + v3(p[RIGHT_HIP])) / 2.0;
    let shoulders = (v3(p[LEFT_SHOULDER]) + v3(p[RIGHT_SHOULDER])) / 2.0;
    let m = hips_frame(v3(p[RIGHT_HIP]) - v3(p[LEFT_HIP]), shoulders - hips, true)?;
    let dir = |a: usize, b: usize| (m * (v3(p[b]) - v3(p[a]))).try_normalize(1e-6);
    let arm = |s: usize, e: usize, w: usize| -> Option<(Vector3<f32>, Vector3<f32>)> {
        (seen(e) && seen(w)).then(|| Some((dir(s, e)?, dir(e, w)?))).flatten()
    };
    let hand = |side: Side| -> Option<[Vector3<f32>; HAND_LANDMARKS]> {
        let h = f.hand(side)?;
        let w = Vector3::from(h[0]);
        Some(std::array::from_fn(|i| m * (Vector3::from(h[i]) - w)))
    };
    let face = (seen(NOSE) && seen(LEFT_EAR) && seen(RIGHT_EAR))
        .then(|| (m * (v3(p[NOSE]) - (v3(p[LEFT_EAR]) + v3(p[RIGHT_EAR])) / 2.0)).try_normalize(1e-6))
        .flatten();
    Some(Observed {
        shoulders: m * (v3(p[RIGHT_SHOULDER]) - v3(p[LEFT_SHOULDER])),
        arms: [arm(LEFT_SHOULDER, LEFT_ELBOW, LEFT_WRIST), arm(RIGHT_SHOULDER, RIGHT_ELBOW, RIGHT_WRIST)],
        hands: [hand(Side::Left), hand(Side::Right)],
        face,
    })
}

/// Our skeleton's hips frame at rest, as the columns of the map from hips-frame directions to
/// the skeleton's (hips at the origin, yaw 0).
fn model_axes(sk: &Skeleton) -> Matrix3<f32> {
    let at = |b: Bone| sk.chain(&STANDING, b).0.coords;
    let hips = (at(Bone::LeftUpperLeg) + at(Bone::RightUpperLeg)) / 2.0;
    let shoulders = (at(Bone::LeftUpperArm) + at(Bone::RightUpperArm)) / 2.0;
    let rows = hips_frame(at(Bone::RightUpperLeg) - at(Bone::LeftUpperLeg), shoulders - hips, false)
        .expect("the skeleton's hips and shoulders are apart");
    rows.transpose()
}

fn side_index(s: Side) -> usize {
    match s {
        Side::Left => 0,
        Side::Right => 1,
    }
}

fn angle(a: Vector3<f32>, b: Vector3<f32>) -> f32 {
    a.angle(&b)
}

/// Turns the spine (three twists, equal shares) so the shoulder line turns over the hips as seen.
fn fit_torso(sk: &Skeleton, pose: &mut [f32; MUSCLES], shoulders: Vector3<f32>) {
    let params = [idx::SPINE_TWIST, idx::CHEST_TWIST, idx::UPPER_CHEST_TWIST];
    let goal = Vector3::new(shoulders.x, 0.0, shoulders.z).try_normalize(1e-6).unwrap_or(Vector3::x());
    let residual = |m: &[f32; MUSCLES], out: &mut Vec<f32>| {
        out.clear();
        let line = sk.chain(m, Bone::RightUpperArm).0 - sk.chain(m, Bone::LeftUpperArm).0;
        let line = Vector3::new(line.x, 0.0, line.z).normalize();
        out.extend_from_slice((line - goal).as_slice());
        out.push(0.1 * (m[params[0]] - m[params[1]]));
        out.push(0.1 * (m[params[1]] - m[params[2]]));
    };
    least_squares(pose, &params, residual, 20, 1e-8);
}

/// What one arm should do, in the skeleton's axes.
struct ArmGoal {
    upper: Vector3<f32>,
    fore: Vector3<f32>,
    /// Hand direction (wrist → middle knuckle) and the palm's outward normal.
    hand: Option<(Vector3<f32>, Vector3<f32>)>,
}

/// Fits one arm's nine muscles to `goal`, staying near `previous` (the frame before) where the
/// goal leaves freedom (the twist of a straight arm seen without its hand).
fn fit_arm(sk: &Skeleton, pose: &mut [f32; MUSCLES], side: Side, goal: &ArmGoal, previous: &[f32; MUSCLES]) {
    let params = arm_params(side);
    // shoulders (clavicles) are pulled to rest: the arm itself does the pointing
    const STAY: [f32; 9] = [0.15, 0.15, 0.02, 0.02, 0.03, 0.02, 0.03, 0.03, 0.03];
    let (ua, la, hand) = (Bone::upper_arm(side), Bone::lower_arm(side), Bone::hand(side));
    let tip = sk.bone_def(hand).tip.normalize();
    let residual = |m: &[f32; MUSCLES], out: &mut Vec<f32>| {
        out.clear();
        let s = sk.chain(m, ua).0;
        let e = sk.chain(m, la).0;
        let (w, q) = sk.chain(m, hand);
        out.extend_from_slice(((e - s).normalize() - goal.upper).as_slice());
        out.extend_from_slice(((w - e).normalize() - goal.fore).as_slice());
        if let Some((d, n)) = goal.hand {
            out.extend_from_slice((0.6 * (q * tip - d)).as_slice());
            out.extend_from_slice((0.4 * (q * -Vector3::y() - n)).as_slice());
        }
        for (k, &i) in params.iter().enumerate() {
            out.push(STAY[k] * (m[i] - if k < 2 { STANDING[i] } else { previous[i] }));
        }
    };
    least_squares(pose, &params, residual, 40, 1e-8);
}

/// The hand's direction and palm normal from its landmarks (skeleton axes): the normal of the
/// plane through the wrist and the index and little knuckles, facing out of the palm.
fn hand_goal(side: Side, h: &[Vector3<f32>; HAND_LANDMARKS]) -> Option<(Vector3<f32>, Vector3<f32>)> {
    let d = h[MIDDLE_MCP].try_normalize(1e-6)?;
    let n = h[INDEX_MCP].cross(&h[LITTLE_MCP]) * -side.sign();
    let n = (n - d * n.dot(&d)).try_normalize(1e-6)?;
    Some((d, n))
}

/// Where a hand's 21 landmarks sit in our skeleton's pose, relative to its wrist.
fn hand_points(pose: &SkeletonPose, side: Side) -> [Vector3<f32>; HAND_LANDMARKS] {
    let wrist = pose.position(Bone::hand(side));
    let mut out = [Vector3::zeros(); HAND_LANDMARKS];
    for (f, digit) in DIGITS.iter().enumerate() {
        let b = |k: usize| Bone::finger(side, Finger::ALL[f], k);
        let joints = [pose.position(b(0)), pose.position(b(1)), pose.position(b(2)), pose.tip(b(2))];
        for (k, p) in joints.into_iter().enumerate() {
            out[digit[k + 1]] = p - wrist;
        }
    }
    out
}

/// Each digit's joint angles (radians) from a hand's points: at the knuckle its flexion towards
/// the palm and its spread sideways (in the palm's frame), then the bends of the two joints
/// beyond; in `Finger` order. The same function reads the landmarks and our skeleton.
fn finger_angles(side: Side, h: &[Vector3<f32>; HAND_LANDMARKS]) -> Option<[[f32; 4]; 5]> {
    let (_, n) = hand_goal(side, h)?;
    Some(std::array::from_fn(|f| {
        let p = DIGITS[f].map(|i| h[i]);
        let (d, v) = (p[1] - p[0], p[2] - p[1]);
        let d = (d - n * d.dot(&n)).try_normalize(1e-6).unwrap_or(d);
        let s = n.cross(&d);
        let along = v.dot(&d);
        [v.dot(&n).atan2(along), v.dot(&s).atan2(along), angle(p[3] - p[2], v), angle(p[4] - p[3], p[3] - p[2])]
    }))
}

/// Sets a hand's 20 finger muscles so that its joints bend and spread as `goal`.
fn fit_fingers(sk: &Skeleton, pose: &mut [f32; MUSCLES], side: Side, goal: &[[f32; 4]; 5]) {
    let params: Vec<usize> = (0..20).map(|k| side.finger_muscles() + k).collect();
    let residual = |m: &[f32; MUSCLES], out: &mut Vec<f32>| {
        out.clear();
        let ours = finger_angles(side, &hand_points(&sk.pose(m, Point3::origin(), 0.0), side));
        for (f, g) in goal.iter().enumerate() {
            for k in 0..4 {
                out.push(ours.map_or(0.0, |o| o[f][k] - g[k]));
            }
            // spread is weakly seen (a flat angle in the palm): kept near relaxed
            out.push(0.05 * (m[side.finger_muscles() + 4 * f + 1] - RELAXED[4 * f + 1]));
        }
    };
    least_squares(pose, &params, residual, 15, 1e-6);
}

/// Turns and nods neck and head (equal shares) so the face points along `face` (skeleton axes).
fn fit_head(sk: &Skeleton, pose: &mut [f32; MUSCLES], face: Vector3<f32>) {
    let params = [idx::NECK_NOD, idx::NECK_TURN, idx::HEAD_NOD, idx::HEAD_TURN];
    let residual = |m: &[f32; MUSCLES], out: &mut Vec<f32>| {
        out.clear();
        let q = sk.chain(m, Bone::Head).1;
        out.extend_from_slice((q * Vector3::z() - face).as_slice());
        out.push(0.05 * (m[idx::NECK_TURN] - m[idx::HEAD_TURN]));
        out.push(0.05 * (m[idx::NECK_NOD] - m[idx::HEAD_NOD]));
    };
    least_squares(pose, &params, residual, 20, 1e-8);
}

/// Yaw (about up, + right) and pitch (+ up) of a hips-frame direction, radians.
fn yaw_pitch(d: Vector3<f32>) -> (f32, f32) {
    (d.x.atan2(d.z), d.y.atan2(d.x.hypot(d.z)))
}

fn from_yaw_pitch(yaw: f32, pitch: f32) -> Vector3<f32> {
    Vector3::new(yaw.sin() * pitch.cos(), pitch.sin(), yaw.cos() * pitch.cos())
}

/// How far each arm is from rest in a pose: the wrist's distance from its resting place, in
/// arm lengths.
fn activity(sk: &Skeleton, m: &[f32; MUSCLES], side: Side) -> f32 {
    let rest = sk.chain(&STANDING, Bone::hand(side)).0;
    let s = sk.chain(&STANDING, Bone::upper_arm(side)).0;
    (sk.chain(m, Bone::hand(side)).0 - rest).norm() / (rest - s).norm()
}

/// Muscles of every frame, trimmed to the gesture and set into 100 frames at 30 fps.
pub fn capture(sk: &Skeleton, frames: &[LandmarkFrame], opts: CaptureOptions) -> Result<Capture, CaptureError> {
    let n = frames.len();
    let seconds = match n {
        0 => 0.0,
        _ => frames[n - 1].t - frames[0].t + frames.get(1).map_or(1.0 / FPS, |f| f.t - frames[0].t),
    };
    if seconds < MIN_SECONDS {
        return Err(CaptureError::TooShort { frames: n, seconds });
    }
    let observed: Vec<Option<Observed>> = frames.iter().map(observe).collect();
    let person_frames = observed.iter().filter(|o| o.is_some()).count();
    if person_frames * 2 < n {
        return Err(CaptureError::NoPerson { missing: n - person_frames, frames: n });
    }
    let to_model = model_axes(sk);
    let dt = seconds / n as f32;
    let mut out = body_and_arms(sk, &observed, to_model);
    let (side, span, resting) = gesture_span(sk, &out, dt)?;
    let s = side_index(side);
    let gesture_frames = span.1 - span.0 + 1;
    let seen_hand = (span.0..=span.1).filter(|&i| observed[i].as_ref().is_some_and(|o| o.hands[s].is_some())).count();
    if seen_hand * 2 < gesture_frames && !opts.hands_optional {
        return Err(CaptureError::HandsLost { side, lost: gesture_frames - seen_hand, frames: gesture_frames });
    }
    fingers(sk, &observed, &mut out);
    head(sk, &observed, &mut out, to_model, rest_nod(&observed, &resting));
    let times: Vec<f32> = frames.iter().map(|f| f.t).collect();
    let motion = resample(&out[span.0..=span.1], dt);
    Ok(Capture { frames: out, times, side, span, motion, person_frames, hand_frames: (seen_hand, gesture_frames) })
}

/// Body and arms fitted to each frame, each frame from the one before.
fn body_and_arms(sk: &Skeleton, observed: &[Option<Observed>], to_model: Matrix3<f32>) -> Vec<[f32; MUSCLES]> {
    let mut out = Vec::with_capacity(observed.len());
    let mut pose = STANDING;
    for o in observed {
        let previous = pose;
        if let Some(o) = o {
            fit_torso(sk, &mut pose, to_model * o.shoulders);
            for side in Side::BOTH {
                let Some((upper, fore)) = o.arms[side_index(side)] else { continue };
                let hand = o.hands[side_index(side)].and_then(|h| {
                    let h = h.map(|v| to_model * v);
                    hand_goal(side, &h)
                });
                fit_arm(
                    sk,
                    &mut pose,
                    side,
                    &ArmGoal { upper: to_model * upper, fore: to_model * fore, hand },
                    &previous,
                );
            }
        }
        out.push(pose);
    }

    out
}

/// The gesturing arm, the frames of its gesture (padded by 0.4 s; frames every `dt`) and
/// which frames are at rest (that arm's activity under 30% of its peak). A person watched for
/// longer than one gesture may be seen pointing twice, or caught mid-gesture (a robot looks at
/// someone who repeats it): the gesture is the longest run of activity that the watch saw begin
/// and end, else the longest run.
fn gesture_span(
    sk: &Skeleton,
    out: &[[f32; MUSCLES]],
    dt: f32,
) -> Result<(Side, (usize, usize), Vec<bool>), CaptureError> {
    let n = out.len();
    let act: Vec<[f32; 2]> = out.iter().map(|m| [activity(sk, m, Side::Left), activity(sk, m, Side::Right)]).collect();
    let peak = |s: usize| act.iter().map(|a| a[s]).fold(0.0f32, f32::max);
    let side = if peak(1) >= peak(0) { Side::Right } else { Side::Left };
    let s = side_index(side);
    if peak(s) < 0.25 {
        return Err(CaptureError::NoGesture);
    }
    let resting: Vec<bool> = (0..n).map(|i| act[i][s] < 0.3 * peak(s)).collect();
    let runs = active_runs(&resting, (0.2 / dt).round() as usize);
    let whole = runs.iter().filter(|r| r.0 > 0 && r.1 < n - 1).max_by_key(|r| r.1 - r.0);
    let (first, last) = *whole.or(runs.iter().max_by_key(|r| r.1 - r.0)).expect("the peak is active");
    let pad = (0.4 / dt).round() as usize;
    Ok((side, (first.saturating_sub(pad), (last + pad).min(n - 1)), resting))
}

/// The runs of frames not `resting` (first, last), a rest of up to `gap` frames inside a run
/// (a flicker of the landmarks) not ending it.
fn active_runs(resting: &[bool], gap: usize) -> Vec<(usize, usize)> {
    let mut runs: Vec<(usize, usize)> = Vec::new();
    for i in (0..resting.len()).filter(|&i| !resting[i]) {
        match runs.last_mut() {
            Some(r) if i - r.1 <= gap + 1 => r.1 = i,
            _ => runs.push((i, i)),
        }
    }
    runs
}

/// The face's resting nod: its median in the frames at rest (in every frame with a face if none).
fn rest_nod(observed: &[Option<Observed>], resting: &[bool]) -> f32 {
    let n = observed.len();
    let mut nods: Vec<f32> =
        (0..n).filter(|&i| resting[i]).filter_map(|i| observed[i].as_ref()?.face.map(|f| yaw_pitch(f).1)).collect();
    if nods.is_empty() {
        nods = observed.iter().flatten().filter_map(|o| o.face.map(|f| yaw_pitch(f).1)).collect();
    }
    nods.sort_by(f32::total_cmp);
    nods.get(nods.len() / 2).copied().unwrap_or(0.0)
}

/// Each hand's fingers in the frames it is seen, held where it is not.
fn fingers(sk: &Skeleton, observed: &[Option<Observed>], out: &mut [[f32; MUSCLES]]) {
    for side in Side::BOTH {
        let mut fingers = RELAXED;
        for (i, o) in observed.iter().enumerate() {
            let m = &mut out[i];
            if let Some(h) = o.as_ref().and_then(|o| o.hands[side_index(side)]) {
                let mut p = *m;
                for (k, v) in fingers.iter().enumerate() {
                    p[side.finger_muscles() + k] = *v;
                }
                if let Some(goal) = finger_angles(side, &h) {
                    fit_fingers(sk, &mut p, side, &goal);
                }
                fingers = std::array::from_fn(|k| p[side.finger_muscles() + k]);
            }
            m[side.finger_muscles()..side.finger_muscles() + 20].copy_from_slice(&fingers);
        }
    }
}

/// The head and neck: a face at its resting nod looks as our skeleton's does at rest.
fn head(
    sk: &Skeleton,
    observed: &[Option<Observed>],
    out: &mut [[f32; MUSCLES]],
    to_model: Matrix3<f32>,
    rest_nod: f32,
) {
    let our_nod = yaw_pitch(to_model.transpose() * (sk.chain(&STANDING, Bone::Head).1 * Vector3::z())).1;
    let mut head = STANDING;
    for (i, o) in observed.iter().enumerate() {
        if let Some(face) = o.as_ref().and_then(|o| o.face) {
            let (yaw, pitch) = yaw_pitch(face);
            fit_head(sk, &mut head, to_model * from_yaw_pitch(yaw, pitch - rest_nod + our_nod));
        }
        for k in [idx::NECK_NOD, idx::NECK_TURN, idx::HEAD_NOD, idx::HEAD_TURN] {
            out[i][k] = head[k];
        }
    }
}

/// A gesture of `frames` (every `dt` seconds) in 100 frames at 30 fps: in real time, centred and
/// held at its ends, when it is shorter than 100 frames; evenly compressed when longer.
fn resample(frames: &[[f32; MUSCLES]], dt: f32) -> Motion {
    let duration = frames.len() as f32 * dt;
    let window = FRAMES as f32 / FPS;
    let (scale, offset) = if duration <= window {
        (1.0 / FPS / dt, (frames.len() as f32 - window / dt) / 2.0)
    } else {
        ((frames.len() - 1) as f32 / (FRAMES - 1) as f32, 0.0)
    };
    let mut out = Motion::constant(&frames[0]);
    for t in 0..FRAMES {
        let x = (offset + t as f32 * scale).clamp(0.0, (frames.len() - 1) as f32);
        let (k, w) = (x.floor() as usize, x.fract());
        let (a, b) = (&frames[k], &frames[(k + 1).min(frames.len() - 1)]);
        let f = out.frame_mut(t);
        for i in 0..MUSCLES {
            f[i] = a[i] + (b[i] - a[i]) * w;
        }
    }
    out
}

/// The shoulder → wrist line of `side` in a pose, in the hips frame: the pointing line the
/// closed-loop measurement compares.
pub fn pointing_line(sk: &Skeleton, m: &[f32; MUSCLES], side: Side) -> Vector3<f32> {
    (sk.chain(m, Bone::hand(side)).0 - sk.chain(m, Bone::upper_arm(side)).0).normalize()
}

/// The shoulder → wrist line of `side` as the landmarks of one frame show it (no inverse
/// kinematics), in the skeleton's axes; None where the person or the arm is not seen.
pub fn observed_pointing_line(sk: &Skeleton, f: &LandmarkFrame, side: Side) -> Option<Vector3<f32>> {
    let p = f.pose()?;
    let (s, w) = match side {
        Side::Left => (LEFT_SHOULDER, LEFT_WRIST),
        Side::Right => (RIGHT_SHOULDER, RIGHT_WRIST),
    };
    if p[w][3] < VISIBLE {
        return None;
    }
    let hips = (v3(p[LEFT_HIP]) + v3(p[RIGHT_HIP])) / 2.0;
    let shoulders = (v3(p[LEFT_SHOULDER]) + v3(p[RIGHT_SHOULDER])) / 2.0;
    let m = hips_frame(v3(p[RIGHT_HIP]) - v3(p[LEFT_HIP]), shoulders - hips, true)?;
    (model_axes(sk) * m * (v3(p[w]) - v3(p[s]))).try_normalize(1e-6)
}

/// How far the arm of `side` is from rest in each frame of `m` (wrist travel in arm lengths),
/// and the arm that moves most: the gesturing one.
pub fn arm_activity(sk: &Skeleton, m: &Motion) -> (Side, [Vec<f32>; 2]) {
    let act = Side::BOTH.map(|s| m.frames().iter().map(|f| activity(sk, f, s)).collect::<Vec<f32>>());
    let peak = |v: &Vec<f32>| v.iter().copied().fold(0.0f32, f32::max);
    (if peak(&act[1]) >= peak(&act[0]) { Side::Right } else { Side::Left }, act)
}

/// The landmarks a camera would give of our skeleton in pose `m`: what the tests and the
/// closed-loop check feed back in. `camera` maps the skeleton's axes (x right, y up, z forward)
/// to the landmarks' (x right, y down, z away); hands are in the same units scaled by 1,000.
pub fn landmarks_of(sk: &Skeleton, m: &[f32; MUSCLES], t: f32, camera: &Matrix3<f32>) -> LandmarkFrame {
    let pose = sk.pose(m, Point3::origin(), 0.0);
    let hips = (pose.position(Bone::LeftUpperLeg).coords + pose.position(Bone::RightUpperLeg).coords) / 2.0;
    let cam = |p: Point3<f32>| camera * (p.coords - hips);
    let mut lm = vec![[0.0, 0.0, 0.0, 0.0]; POSE_LANDMARKS];
    let mut put = |i: usize, p: Point3<f32>| {
        let c = cam(p);
        lm[i] = [c.x, c.y, c.z, 1.0];
    };
    let head = pose.head_position();
    let (fwd, up) = (pose.rotation(Bone::Head) * Vector3::z(), pose.rotation(Bone::Head) * Vector3::y());
    let right = pose.rotation(Bone::Head) * Vector3::x();
    put(NOSE, head + fwd * 0.1 - up * 0.03);
    put(LEFT_EAR, head - right * 0.075);
    put(RIGHT_EAR, head + right * 0.075);
    for side in Side::BOTH {
        let (s, e, w, h) = match side {
            Side::Left => (LEFT_SHOULDER, LEFT_ELBOW, LEFT_WRIST, LEFT_HIP),
            Side::Right => (RIGHT_SHOULDER, RIGHT_ELBOW, RIGHT_WRIST, RIGHT_HIP),
        };
        put(s, pose.position(Bone::upper_arm(side)));
        put(e, pose.position(Bone::lower_arm(side)));
        put(w, pose.position(Bone::hand(side)));
        put(h, pose.position(if side == Side::Left { Bone::LeftUpperLeg } else { Bone::RightUpperLeg }));
    }
    let hand = |side: Side| -> Vec<[f32; 3]> {
        let wrist = cam(pose.position(Bone::hand(side)));
        hand_points(&pose, side).iter().map(|p| ((wrist + camera * p) * 1000.0).into()).collect()
    };
    LandmarkFrame {
        t,
        pose: Some(lm),
        left_hand: Some(hand(Side::Left)),
        right_hand: Some(hand(Side::Right)),
        pose_image: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gesture::{Pointing, referencing_with};
    use crate::humanoid::Humanoid;

    /// A camera 30° to the person's left, a little above: skeleton axes → landmark axes
    /// (a reflection: y flips from up to down).
    fn camera() -> Matrix3<f32> {
        let turn = nalgebra::Rotation3::from_euler_angles(0.15, 0.52, 0.0);
        turn.matrix() * Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, 1.0))
    }

    fn filmed(sk: &Skeleton, m: &Motion) -> Vec<LandmarkFrame> {
        let cam = camera();
        (0..FRAMES).map(|t| landmarks_of(sk, m.frame(t), t as f32 / FPS, &cam)).collect()
    }

    #[test]
    fn a_filmed_pointing_gesture_comes_back_pointing_the_same_way() {
        let h = Humanoid::standard();
        let sk = h.skeleton();
        for (k, target) in [Point3::new(1.5, 0.3, 2.0), Point3::new(-2.0, 1.2, 1.0), Point3::new(0.4, 0.8, 3.0)]
            .into_iter()
            .enumerate()
        {
            let (m, style) = referencing_with(h, Pointing::Clean, k as u64, Point3::origin(), 0.0, target);
            let c = capture(sk, &filmed(sk, &m), CaptureOptions::default()).unwrap();
            assert_eq!(c.side, style.side, "the pointing arm");
            let hold = (style.lead + style.rise + style.hold / 2) as usize;
            let err =
                pointing_line(sk, m.frame(hold), style.side).angle(&pointing_line(sk, &c.frames[hold], style.side));
            assert!(err.to_degrees() < 3.0, "target {target:?}: shoulder→wrist off by {:.1}°", err.to_degrees());
            // the hand shape too: the index finger's angles are the original's
            let angles = |m: &[f32; MUSCLES]| {
                finger_angles(style.side, &hand_points(&sk.pose(m, Point3::origin(), 0.0), style.side)).unwrap()
            };
            let (a, b) = (angles(m.frame(hold)), angles(&c.frames[hold]));
            for k in 0..4 {
                assert!((a[1][k] - b[1][k]).abs() < 0.1, "index angle {k}: {} vs {}", a[1][k], b[1][k]);
            }
            // the span holds the whole gesture (lead-in to return)
            assert!(c.span.0 <= style.lead as usize && c.span.1 + 1 >= (style.lead + style.rise + style.hold) as usize);
        }
    }

    #[test]
    fn a_repeated_gesture_watched_from_its_middle_comes_back_whole() {
        let h = Humanoid::standard();
        let sk = h.skeleton();
        let (m, style) = referencing_with(h, Pointing::Clean, 1, Point3::origin(), 0.0, Point3::new(1.5, 0.3, 2.0));
        // watched for two gestures' time from the middle of the hold: the end of one, a whole
        // one, the start of a third
        let from = (style.lead + style.rise + style.hold / 2) as usize;
        let frames: Vec<LandmarkFrame> = (0..2 * FRAMES)
            .map(|i| landmarks_of(sk, m.frame((from + i) % FRAMES), i as f32 / FPS, &camera()))
            .collect();
        let c = capture(sk, &frames, CaptureOptions::default()).unwrap();
        assert_eq!(c.side, style.side);
        // the whole gesture: from rest, up, held, and down again
        let act = |f: &[f32; MUSCLES]| activity(sk, f, style.side);
        let top = (0..FRAMES).map(|t| act(c.motion.frame(t))).fold(0.0f32, f32::max);
        assert!(act(c.motion.frame(0)) < 0.3 * top && act(c.motion.frame(FRAMES - 1)) < 0.3 * top);
        let hold = (0..FRAMES).max_by(|&a, &b| act(c.motion.frame(a)).total_cmp(&act(c.motion.frame(b)))).unwrap();
        let err =
            pointing_line(sk, m.frame(from), style.side).angle(&pointing_line(sk, c.motion.frame(hold), style.side));
        assert!(err.to_degrees() < 3.0, "shoulder→wrist off by {:.1}°", err.to_degrees());
        // the gesture lasts as long as it did, not squeezed from two into one
        let span = c.span.1 - c.span.0 + 1;
        assert!(span <= FRAMES, "{span} frames");
    }

    #[test]
    fn the_face_and_the_palm_come_back() {
        let h = Humanoid::standard();
        let sk = h.skeleton();
        let mut m = STANDING;
        m[idx::HEAD_TURN] = 0.5;
        m[idx::NECK_TURN] = 0.5;
        m[idx::RIGHT_ARM + idx::ARM_DOWN_UP] = 0.3;
        m[idx::RIGHT_ARM + idx::FOREARM_TWIST] = 0.6;
        let mut frames = vec![landmarks_of(sk, &STANDING, 0.0, &camera()); 40];
        for (i, f) in frames.iter_mut().enumerate() {
            f.t = i as f32 / FPS;
        }
        for f in &mut frames[15..30] {
            *f = LandmarkFrame { t: f.t, ..landmarks_of(sk, &m, f.t, &camera()) };
        }
        let c = capture(sk, &frames, CaptureOptions::default()).unwrap();
        let (want, got) = (sk.pose(&m, Point3::origin(), 0.0), sk.pose(&c.frames[25], Point3::origin(), 0.0));
        assert!(want.head_forward().angle(&got.head_forward()).to_degrees() < 3.0);
        assert!(want.palm_normal(Side::Right).angle(&got.palm_normal(Side::Right)).to_degrees() < 10.0);
        // 40 frames at 30 fps are shorter than 100: real time, held at the ends
        assert_eq!(c.motion.frame(0), &c.frames[c.span.0]);
    }

    #[test]
    fn bad_videos_get_one_line_each() {
        let sk = Humanoid::standard().skeleton();
        let still: Vec<LandmarkFrame> =
            (0..60).map(|i| landmarks_of(sk, &STANDING, i as f32 / FPS, &camera())).collect();
        assert_eq!(capture(sk, &still[..20], CaptureOptions::default()).unwrap_err().to_string().lines().count(), 1);
        assert!(matches!(capture(sk, &still[..20], CaptureOptions::default()), Err(CaptureError::TooShort { .. })));
        assert_eq!(capture(sk, &still, CaptureOptions::default()).unwrap_err(), CaptureError::NoGesture);
        let mut empty = still.clone();
        for f in &mut empty[..40] {
            f.pose = None;
        }
        assert_eq!(
            capture(sk, &empty, CaptureOptions::default()).unwrap_err(),
            CaptureError::NoPerson { missing: 40, frames: 60 }
        );
        let (m, style) = referencing_with(
            Humanoid::standard(),
            Pointing::Clean,
            3,
            Point3::origin(),
            0.0,
            Point3::new(1.0, 0.5, 2.0),
        );
        let mut handless = filmed(sk, &m);
        for f in &mut handless {
            (f.left_hand, f.right_hand) = (None, None);
        }
        let e = capture(sk, &handless, CaptureOptions::default()).unwrap_err();
        assert!(matches!(e, CaptureError::HandsLost { side, .. } if side == style.side), "{e}");
        assert!(capture(sk, &handless, CaptureOptions { hands_optional: true }).is_ok());
    }
}
