//! The person as the robot's own camera sees them (`--gesture camera`): the landmark model of
//! the live page's webcam (MediaPipe) reads each colour frame. At an episode's start the
//! gesture is captured for `--capture-seconds` and fitted to the 95 muscles as `gesture capture`
//! fits a video; where the person stands is read from the aligned depth under their hips, and
//! which way they face from the line of their hips. A wave calls the intervention, as on the
//! live page.
//!
//! With `--gesture skeleton` a tracker finds the person instead (REP-155's `skeleton2d`: 18
//! keypoints in the image); the aligned depth measures each keypoint in 3-D, and the capture
//! reads them as it reads the landmark model's.

use shm_schema::{GESTURE_DIMS, GESTURE_FRAMES, gesture_kind};
use worker::gesture::capture::LandmarkFrame;
use worker::humanoid::Humanoid;

use super::drive::{Pose2, wrap};
use super::msgs::{CameraInfo, Gesture, Header, Image, Pose, Skeleton2D};
use crate::commands::live::gesture::muscles;
use crate::commands::live::webcam::{Webcam, remember, waving};

/// MediaPipe's pose landmarks of the hips: the person's left, right.
const HIPS: [usize; 2] = [23, 24];

/// What the camera has told of the person.
pub struct Person {
    /// The landmark model, where it reads the colour frames (not with a tracker's skeletons).
    webcam: Option<Webcam>,
    capture_seconds: f64,
    /// The capture under way: from when (ROS time), and its frames.
    capturing: Option<(f64, Vec<LandmarkFrame>)>,
    /// The captured gesture's muscles, and where the person stood then (odometry frame).
    referencing: Option<(Vec<f32>, Pose2)>,
    /// The last frames, for a wave (ROS time in `t`).
    recent: Vec<LandmarkFrame>,
    intervention: Vec<f32>,
    /// The robot should turn this way (`action::ROTATE_*`) before it watches: nobody is in
    /// view, or the person is not before the camera.
    pub look: Option<u8>,
    /// Captures tried this episode.
    tries: u32,
    /// Between captures the landmark model reads a frame this often at most (s, ROS time),
    /// and last read one then.
    wave_period: f64,
    last_read: f64,
}

/// Captures that found a person but no gesture, before the episode goes on without one.
const TRIES: u32 = 2;

impl Person {
    /// `wave_rate`: frames a second read between captures (0: every frame); `model`: the
    /// landmark model reads the colour frames (else a tracker's skeletons come to `see_skeleton`).
    pub fn start(capture_seconds: f64, wave_rate: f64, model: bool) -> anyhow::Result<Person> {
        Ok(Person {
            webcam: if model { Some(Webcam::start()?) } else { None },
            capture_seconds,
            capturing: None,
            referencing: None,
            recent: Vec::new(),
            intervention: worker::gesture::intervention(0).as_flat().to_vec(),
            look: None,
            tries: 0,
            wave_period: if wave_rate > 0.0 { 1.0 / wave_rate } else { 0.0 },
            last_read: f64::NEG_INFINITY,
        })
    }

    /// A new episode: the person's gesture is captured afresh from `now` on.
    pub fn begin(&mut self, now: f64) {
        self.capturing = Some((now, Vec::new()));
        self.referencing = None;
        self.look = None;
        self.tries = 0;
        self.last_read = f64::NEG_INFINITY;
    }

    /// Watches again from `now` (after a turn to look for the person).
    pub fn watch(&mut self, now: f64) {
        self.capturing = Some((now, Vec::new()));
        self.look = None;
    }

    /// No person was found: the episode goes on without their gesture, where the robot stands.
    pub fn give_up(&mut self, robot: Pose2) {
        self.capturing = None;
        self.look = None;
        self.referencing = Some((Vec::new(), robot));
    }

    /// The person's gesture was read this episode, or given up on.
    pub fn watched(&self) -> bool {
        self.referencing.is_some()
    }

    /// The landmark model reads the colour frames (not a tracker's skeletons).
    pub fn reads_frames(&self) -> bool {
        self.webcam.is_some()
    }

    pub fn capturing(&self) -> bool {
        self.capturing.is_some()
    }

    /// Reads one colour frame (and its depth) taken where the robot stood at `robot`.
    pub fn see(&mut self, colour: &Image, depth: &Image, info: &CameraInfo, robot: Pose2) -> anyhow::Result<()> {
        let t = super::dds::seconds(colour.header.stamp);
        if self.resting(t) {
            return Ok(());
        }
        let jpeg = jpeg(colour)?;
        let webcam = self.webcam.as_mut().ok_or_else(|| anyhow::anyhow!("no landmark model: a tracker's skeletons"))?;
        let mut f = webcam.read(&jpeg, std::time::Instant::now())?;
        let hips = hips(&f, depth, info);
        if let Some(h) = hips {
            lift(&mut f, h, depth, info);
        }
        self.look_at(f, t, hips, info, robot);
        Ok(())
    }

    /// Reads a tracker's skeleton of the person (`None`: it tracked nobody) in the frame whose
    /// aligned depth is `depth`. A keypoint the depth does not place on the person is not seen.
    pub fn see_skeleton(&mut self, body: Option<&Skeleton2D>, depth: &Image, info: &CameraInfo, robot: Pose2) {
        let t = super::dds::seconds(depth.header.stamp);
        if self.resting(t) {
            return;
        }
        let mut f = body.map_or_else(LandmarkFrame::default, |b| landmarks(b, info));
        let hips = hips(&f, depth, info);
        match hips {
            Some(h) => {
                let measured = lift(&mut f, h, depth, info);
                for (p, m) in f.pose.iter_mut().flatten().zip(measured) {
                    if !m {
                        p[3] = 0.0;
                    }
                }
            }
            // hips unseen or unmeasured: nobody the capture can read
            None => f = LandmarkFrame::default(),
        }
        self.look_at(f, t, hips, info, robot);
    }

    /// Between captures a frame is read only every `wave_period` (for a wave).
    fn resting(&mut self, t: f64) -> bool {
        // a wave is read from a few frames a second: the model at every frame would hold up the
        // control loop (≈ 0.1 s a frame on two cores)
        if self.capturing.is_none() && (t - self.last_read).abs() < self.wave_period {
            return true;
        }
        self.last_read = t;
        false
    }

    /// One frame's landmarks of the person (measured in 3-D where the hips were): kept for a
    /// wave, and watched for the gesture while a capture is under way.
    fn look_at(&mut self, mut f: LandmarkFrame, t: f64, hips: Option<Hips>, info: &CameraInfo, robot: Pose2) {
        f.t = t as f32;
        remember(&mut self.recent, f.clone());
        let Some((from, frames)) = &mut self.capturing else { return };
        if frames.is_empty() {
            // nobody in view: look elsewhere rather than watch an empty room; someone off to a
            // side: turn to them first, for their arms may leave the frame
            self.look = match (&f.pose, off_axis(&f, info)) {
                (None, _) => Some(shm_schema::action::ROTATE_LEFT),
                (Some(_), Some(deg)) if deg.abs() > CENTRED_DEG => {
                    Some(if deg < 0.0 { shm_schema::action::ROTATE_LEFT } else { shm_schema::action::ROTATE_RIGHT })
                }
                _ => None,
            };
            if self.look.is_some() {
                self.capturing = None;
                return;
            }
        }
        f.t = (t - *from) as f32;
        let stood = hips.map(|h| stands(h, robot));
        frames.push(f);
        if t - *from < self.capture_seconds {
            return;
        }
        let (_, frames) = self.capturing.take().expect("under way");
        match (muscles(Humanoid::seeded(0).skeleton(), &frames), stood) {
            (Ok(c), Some(at)) => {
                say!(
                    "the person's gesture read ({} arm, {} of {} frames), the person at ({:.2}, {:.2}) facing {:.0}°",
                    crate::commands::live::gesture::arm_name(c.side),
                    c.person_frames,
                    frames.len(),
                    at.x,
                    at.y,
                    at.yaw.to_degrees()
                );
                self.referencing = Some((c.motion.as_flat().to_vec(), at));
            }
            (Err(e), _) => self.fail(t, format!("the person's gesture was not read: {e:#}"), robot),
            (Ok(_), None) => self.fail(
                t,
                "the person's gesture was read, but not where they stand (no depth under their hips)".into(),
                robot,
            ),
        }
    }

    /// A capture that found no gesture starts again, then the episode goes on without one.
    fn fail(&mut self, t: f64, why: String, robot: Pose2) {
        self.tries += 1;
        say!("{why}");
        match self.tries < TRIES {
            true => self.capturing = Some((t, Vec::new())),
            false => self.give_up(robot),
        }
    }

    /// What the capture read, published for those who watch (and judged by `robot sim`): the
    /// person's gesture (no muscles when none was read) and where they stood.
    pub fn reading(&self, stamp: f64, odom: &str) -> Option<Gesture> {
        let (referencing, at) = self.referencing.as_ref()?;
        let kind = if referencing.is_empty() { gesture_kind::NONE } else { gesture_kind::REFERENCING };
        Some(message(kind, referencing.clone(), *at, stamp, odom))
    }

    /// The gesture the policy is shown with a frame stamped `stamp`, in `odom`'s frame: the
    /// captured one, or the intervention while the person waves (as `schedule` shows them).
    pub fn gesture(&self, schedule: farm::config::GestureSchedule, stamp: f64, odom: &str) -> Option<Gesture> {
        let (referencing, at) = self.referencing.as_ref()?;
        let mut kind = worker::env::shown(schedule, waving(&self.recent));
        if kind == gesture_kind::REFERENCING && referencing.is_empty() {
            kind = gesture_kind::NONE;
        }
        let muscles = match kind {
            gesture_kind::REFERENCING => referencing.clone(),
            gesture_kind::INTERVENTION => self.intervention.clone(),
            _ => Vec::new(),
        };
        Some(message(kind, muscles, *at, stamp, odom))
    }
}

fn message(kind: u8, muscles: Vec<f32>, at: Pose2, stamp: f64, odom: &str) -> Gesture {
    let size = |n: usize| if muscles.is_empty() { 0 } else { n as u16 };
    Gesture {
        header: Header::new(super::dds::time(stamp), odom),
        kind,
        person: Pose::planar(at.x, at.y, at.yaw),
        frames: size(GESTURE_FRAMES),
        dims: size(GESTURE_DIMS),
        muscles,
    }
}

/// The hips in the optical frame (left, right), each where the aligned depth puts it along its
/// pixel's ray: the median of the values measured within two pixels.
type Hips = ([f64; 3], [f64; 3]);

fn hips(f: &LandmarkFrame, depth: &Image, info: &CameraInfo) -> Option<Hips> {
    let img = f.pose_image.as_ref()?;
    let median = |v: &[f64]| v[v.len() / 2];
    Some((optical(*img.get(HIPS[0])?, depth, info, median)?, optical(*img.get(HIPS[1])?, depth, info, median)?))
}

/// A landmark's point in the optical frame (x right, y down, z ahead; m): its pixel lifted along
/// its ray to the depth `pick` takes from those measured within two pixels (nearest first).
fn optical(px: [f32; 2], depth: &Image, info: &CameraInfo, pick: fn(&[f64]) -> f64) -> Option<[f64; 3]> {
    let (u, v) = (px[0] as f64, px[1] as f64);
    // off the image (a landmark guessed beyond its edge, a keypoint not found): not measured
    if !(u >= 0.0 && v >= 0.0 && u < depth.width as f64 && v < depth.height as f64) {
        return None;
    }
    let d = pick(&depth_values(depth, u as i64, v as i64)?);
    Some([(u - info.k[2]) / info.k[0] * d, (v - info.k[5]) / info.k[4] * d, d])
}

/// Where the person stands and faces in the odometry frame: between their hips, facing square
/// to the line from their right hip to their left.
fn stands((l, r): Hips, robot: Pose2) -> Pose2 {
    let (x, z) = ((l[0] + r[0]) / 2.0, (l[2] + r[2]) / 2.0);
    // their left (lx, lz); they face (lz, −lx), which is (ahead, left) = (−lx, −lz) for the robot
    let (lx, lz) = (l[0] - r[0], l[2] - r[2]);
    let facing = (-lz).atan2(-lx);
    let (ahead, left) = (z, -x);
    let (s, c) = robot.yaw.sin_cos();
    Pose2 { x: robot.x + ahead * c - left * s, y: robot.y + ahead * s + left * c, yaw: wrap(robot.yaw + facing) }
}

/// How far off the camera's axis the person may stand when their gesture is watched (degrees;
/// more than half a turn, so that turning to them does not overshoot).
const CENTRED_DEG: f64 = 10.0;

/// How far right of the camera's axis the person's hips are (degrees; left is negative).
fn off_axis(f: &LandmarkFrame, info: &CameraInfo) -> Option<f64> {
    let img = f.pose_image.as_ref()?;
    let u = (img.get(HIPS[0])?[0] + img.get(HIPS[1])?[0]) as f64 / 2.0;
    Some(((u - info.k[2]) / info.k[0]).atan().to_degrees())
}

/// How far from the hips a measured landmark may lie and still be the person's (m).
const REACH: f64 = 1.2;

/// The pose's world landmarks measured by the aligned depth: each landmark's pixel lifted
/// along its ray to the nearest surface within two pixels (a limb before the room behind it),
/// about the hips' midpoint, in the model's axes (x right, y down, z away). The landmark model
/// guesses from one image how far an arm reaches toward the camera; the depth measures it. A
/// landmark whose depth is no part of the person (over [`REACH`] from the hips) keeps the
/// model's guess. Which landmarks were measured.
fn lift(f: &mut LandmarkFrame, (l, r): Hips, depth: &Image, info: &CameraInfo) -> Vec<bool> {
    let (Some(img), Some(pose)) = (f.pose_image.as_ref(), f.pose.as_mut()) else { return Vec::new() };
    if img.len() != pose.len() {
        return vec![false; pose.len()];
    }
    let mid: [f64; 3] = std::array::from_fn(|k| (l[k] + r[k]) / 2.0);
    let mut measured = vec![false; pose.len()];
    for ((px, p), m) in img.iter().zip(pose.iter_mut()).zip(measured.iter_mut()) {
        let Some(q) = optical(*px, depth, info, |v| v[0]) else { continue };
        let rel: [f64; 3] = std::array::from_fn(|k| q[k] - mid[k]);
        if rel.iter().map(|x| x * x).sum::<f64>().sqrt() < REACH {
            (p[0], p[1], p[2]) = (rel[0] as f32, rel[1] as f32, rel[2] as f32);
            *m = true;
        }
    }
    measured
}

/// MediaPipe's pose landmark for each of REP-155's 18 keypoints (OpenPose's COCO order): nose,
/// neck (none), right shoulder, elbow, wrist, left shoulder, elbow, wrist, right hip, knee,
/// ankle, left hip, knee, ankle, left eye, right eye, left ear, right ear.
const COCO: [Option<usize>; 18] = [
    Some(0),
    None,
    Some(12),
    Some(14),
    Some(16),
    Some(11),
    Some(13),
    Some(15),
    Some(24),
    Some(26),
    Some(28),
    Some(23),
    Some(25),
    Some(27),
    Some(2),
    Some(5),
    Some(7),
    Some(8),
];

/// A tracker's keypoints as the landmark model's 33: each found one at its pixel, its
/// confidence as the visibility, its 3-D place yet to be measured; the rest off the image.
fn landmarks(b: &Skeleton2D, info: &CameraInfo) -> LandmarkFrame {
    let mut img = vec![[-1.0f32; 2]; worker::gesture::capture::POSE_LANDMARKS];
    let mut pose = vec![[0.0f32; 4]; img.len()];
    for (k, mp) in b.skeleton.iter().zip(COCO) {
        let Some(i) = mp.filter(|_| k.c > 0.0 && k.x.is_finite() && k.y.is_finite()) else { continue };
        img[i] = [k.x * info.width as f32, k.y * info.height as f32];
        pose[i][3] = k.c;
    }
    LandmarkFrame { pose: Some(pose), pose_image: Some(img), ..Default::default() }
}

/// The measured values (m) within two pixels of (u, v), nearest first; none measured: `None`.
fn depth_values(depth: &Image, u: i64, v: i64) -> Option<Vec<f64>> {
    let (metres, bytes) = super::camera::depth_pixel(depth).ok()?;
    let mut vals = Vec::new();
    for y in (v - 2).max(0)..=(v + 2).min(depth.height as i64 - 1) {
        for x in (u - 2).max(0)..=(u + 2).min(depth.width as i64 - 1) {
            let at = y as usize * depth.step as usize + x as usize * bytes;
            let m = metres(depth.data.get(at..at + bytes)?) as f64;
            if m.is_finite() && m > 0.0 {
                vals.push(m);
            }
        }
    }
    vals.sort_by(f64::total_cmp);
    (!vals.is_empty()).then_some(vals)
}

/// The colour image as a JPEG for the landmark model.
fn jpeg(img: &Image) -> anyhow::Result<Vec<u8>> {
    let (ch, colour) = match img.encoding.as_str() {
        "rgb8" => (3, jpeg_encoder::ColorType::Rgb),
        "bgr8" => (3, jpeg_encoder::ColorType::Bgr),
        "rgba8" => (4, jpeg_encoder::ColorType::Rgba),
        "bgra8" => (4, jpeg_encoder::ColorType::Bgra),
        other => anyhow::bail!("colour image: encoding `{other}`"),
    };
    let row = img.width as usize * ch;
    let packed: Vec<u8> =
        (0..img.height as usize).flat_map(|y| img.data[y * img.step as usize..][..row].iter().copied()).collect();
    let mut out = Vec::new();
    jpeg_encoder::Encoder::new(&mut out, 90).encode(&packed, img.width as u16, img.height as u16, colour)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::commands::robot::camera::pinhole;

    /// A 640×480 16UC1 image, `mm` everywhere but `(u, v, mm)` patches.
    fn depth(mm: u16, patches: &[(usize, usize, u16)]) -> Image {
        let (w, h) = (640usize, 480usize);
        let mut px = vec![mm; w * h];
        for &(u, v, d) in patches {
            for y in v - 3..=v + 3 {
                for x in u - 3..=u + 3 {
                    px[y * w + x] = d;
                }
            }
        }
        Image {
            header: Header::default(),
            height: h as u32,
            width: w as u32,
            encoding: "16UC1".into(),
            is_bigendian: 0,
            step: w as u32 * 2,
            data: px.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }

    fn hips_at(left: (f32, f32), right: (f32, f32)) -> LandmarkFrame {
        let mut img = vec![[0.0; 2]; 33];
        (img[HIPS[0]], img[HIPS[1]]) = ([left.0, left.1], [right.0, right.1]);
        LandmarkFrame { pose_image: Some(img), ..Default::default() }
    }

    #[test]
    fn a_person_facing_the_robot_stands_where_the_depth_says_and_faces_it() {
        let info = pinhole(640, 480, 90.0, Header::default());
        // 2 m ahead, square to the camera: their left hip on the image's right
        let f = hips_at((359.5, 239.5), (279.5, 239.5));
        let at = stands(hips(&f, &depth(2000, &[]), &info).unwrap(), Pose2::default());
        assert!((at.x - 2.0).abs() < 1e-6 && at.y.abs() < 1e-6, "{at:?}");
        assert!((wrap(at.yaw - std::f64::consts::PI)).abs() < 1e-6, "{at:?}");
        // the robot elsewhere: the same person seen from (1, 1) facing +y stands at (1, 3)
        let robot = Pose2 { x: 1.0, y: 1.0, yaw: std::f64::consts::FRAC_PI_2 };
        let at = stands(hips(&f, &depth(2000, &[]), &info).unwrap(), robot);
        assert!((at.x - 1.0).abs() < 1e-6 && (at.y - 3.0).abs() < 1e-6, "{at:?}");
        assert!((wrap(at.yaw + std::f64::consts::FRAC_PI_2)).abs() < 1e-6, "{at:?}");
    }

    #[test]
    fn the_depth_measures_how_far_an_arm_reaches_toward_the_camera() {
        let info = pinhole(640, 480, 90.0, Header::default());
        // hips 2 m ahead, a wrist 0.5 m nearer the camera, an elbow over the room 5 m away
        let mut f = hips_at((359.5, 239.5), (279.5, 239.5));
        let img = f.pose_image.as_mut().unwrap();
        (img[16], img[14]) = ([399.5, 199.5], [100.0, 100.0]);
        f.pose = Some(vec![[0.0, 0.0, 0.0, 1.0]; 33]);
        f.pose.as_mut().unwrap()[14] = [0.3, -0.2, -0.1, 1.0];
        let d = depth(2000, &[(400, 200, 1500), (100, 100, 5000)]);
        let h = hips(&f, &d, &info).unwrap();
        lift(&mut f, h, &d, &info);
        let pose = f.pose.unwrap();
        // the wrist: 0.5 m nearer than the hips, and where its pixel's ray puts it
        let w = pose[16];
        assert!((w[2] + 0.5).abs() < 1e-3, "{w:?}");
        assert!((w[0] - 0.5).abs() < 1e-3 && (w[1] + 0.25).abs() < 1e-3, "{w:?}");
        // the hips: about their midpoint
        assert!(pose[23][0] > 0.0 && (pose[23][0] + pose[24][0]).abs() < 1e-3, "{:?}", pose[23]);
        // no part of the person 3 m behind them: the model's guess stays
        assert_eq!(pose[14], [0.3, -0.2, -0.1, 1.0]);
    }

    #[test]
    fn a_trackers_keypoints_are_the_landmark_models_and_only_the_measured_are_seen() {
        let info = pinhole(640, 480, 90.0, Header::default());
        let mut b = Skeleton2D { header: Header::default(), skeleton: Default::default() };
        let at = |x: f32, y: f32| crate::commands::robot::msgs::NormalizedPoint { x: x / 640.0, y: y / 480.0, c: 0.9 };
        // COCO's left hip (11), right hip (8), left wrist (7); the right wrist (4) not found
        (b.skeleton[11], b.skeleton[8], b.skeleton[7]) = (at(359.5, 239.5), at(279.5, 239.5), at(399.5, 199.5));
        let mut f = landmarks(&b, &info);
        let img = f.pose_image.clone().unwrap();
        assert_eq!((img[23], img[24], img[15]), ([359.5, 239.5], [279.5, 239.5], [399.5, 199.5]));
        assert_eq!(f.pose.as_ref().unwrap()[15][3], 0.9);
        // not found: off the image, never measured there
        assert!(img[16][0] < 0.0 && f.pose.as_ref().unwrap()[16][3] == 0.0);
        let d = depth(2000, &[(400, 200, 1500)]);
        let h = hips(&f, &d, &info).unwrap();
        let measured = lift(&mut f, h, &d, &info);
        assert!(measured[15] && measured[23] && !measured[16], "{measured:?}");
        // the wrist: 0.5 m nearer the camera than the hips
        assert!((f.pose.unwrap()[15][2] + 0.5).abs() < 1e-3);
    }

    #[test]
    fn a_person_turned_to_their_right_has_their_left_hip_nearer() {
        let info = pinhole(640, 480, 90.0, Header::default());
        // facing the camera, turned to their right: their left hip nearer
        let f = hips_at((400.0, 239.5), (240.0, 239.5));
        let d = depth(2000, &[(400, 240, 1850), (240, 240, 2150)]);
        let at = stands(hips(&f, &d, &info).unwrap(), Pose2::default());
        // they face the robot, turned toward its left
        assert!(at.yaw > std::f64::consts::FRAC_PI_2 && at.yaw < std::f64::consts::PI, "{:.1}°", at.yaw.to_degrees());
        // no depth under a hip: no place
        assert!(hips(&f, &depth(0, &[]), &info).is_none());
    }
}
