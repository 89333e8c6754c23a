//! BVH motion capture ↔ the 95 muscles.
//!
//! **Import** retargets a BVH skeleton to the humanoid: joints are matched to humanoid bones by
//! name (Mixamo `mixamorig:LeftForeArm`, CMU `LeftForeArm`/`LThumb`, Unity `LeftLowerArm`, and
//! the usual `Thigh`/`Shin`/`Clavicle`/`Wrist` spellings), each frame's joint rotations are
//! turned into every bone's rotation relative to its parent, those are split into swing and
//! twist about the bone's muscle axes, divided by the muscle ranges and clamped to [−1, 1].
//! The BVH's own rest pose may differ from a T-pose (an A-pose, say): each bone's rest
//! direction is aligned with the humanoid's first. The result is resampled to 100 frames at
//! 30 fps (the first 3.3 s; a shorter clip holds its last frame). Bones the file lacks keep
//! natural standing.
//!
//! **Export** writes a motion on the humanoid's skeleton as BVH (Y up, centimetres, ZXY Euler
//! channels), so gestures can be inspected in any motion-capture viewer; importing it again
//! gives the muscles back.

use std::path::Path;

use bvh_anim::{Bvh, ChannelType};
use nalgebra::{Matrix3, Point3, Rotation3, UnitQuaternion, Vector3};

use super::synth::STANDING;
use super::{FPS, FRAMES, Motion};
use crate::humanoid::skeleton::{BoneDef, EVAL_ORDER};
use crate::humanoid::{BONES, Bone, Finger, Humanoid, MUSCLES, Side, Skeleton, muscle_value};

/// A BVH file that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum BvhError {
    #[error("{file}: cannot read: {reason}")]
    Io { file: String, reason: std::io::Error },
    #[error("{file}: {line}{message}")]
    Parse { file: String, line: String, message: String },
    #[error("{file}: {message}")]
    Skeleton { file: String, message: String },
}

/// Imports a BVH file as a gesture on the default body.
pub fn import(path: &Path) -> Result<Motion, BvhError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|reason| BvhError::Io { file: file.clone(), reason })?;
    import_bytes(&bytes, &file)
}

/// Imports BVH text; `file` names the source in errors.
pub fn import_bytes(bytes: &[u8], file: &str) -> Result<Motion, BvhError> {
    let parse_err = |line: Option<usize>, message: String| BvhError::Parse {
        file: file.to_string(),
        line: line.map(|l| format!("line {l}: ")).unwrap_or_default(),
        message,
    };
    let text = std::str::from_utf8(bytes).map_err(|e| parse_err(None, format!("not UTF-8 text ({e})")))?;
    let clean = sanitize(text).map_err(|(line, message)| parse_err(Some(line), message))?;
    // `sanitize` rules out the inputs the parser is known to panic on; should another one
    // slip through, it is still a bad file, not a crash.
    let parsed = std::panic::catch_unwind(|| bvh_anim::from_bytes(clean.as_bytes()))
        .map_err(|_| parse_err(None, "not a readable BVH file: malformed hierarchy".into()))?;
    // The parser counts lines from 0.
    let bvh = parsed.map_err(|e| parse_err(e.line().map(|l| l + 1), format!("not a readable BVH file: {e}")))?;
    retarget(&bvh, Humanoid::standard(), file)
}

/// Checks the structure `bvh_anim` expects (it panics, or reserves memory for the declared
/// frame count, before checking some of it) and rewrites joint names it would cut: it splits
/// names at `:` and whitespace, so `mixamorig:Hips` becomes `Hips` and `Bip01 L Thigh`
/// becomes `Bip01_L_Thigh`. Errors carry a 1-based line number.
fn sanitize(text: &str) -> Result<String, (usize, String)> {
    let mut s = Sanitizer::default();
    for (i, line) in text.lines().enumerate() {
        let t: Vec<&str> = line.split_whitespace().collect();
        if t.is_empty() {
            s.out.push('\n');
        } else if s.motion {
            s.motion_line(i + 1, &t)?;
            s.keep(line);
        } else if let Some(renamed) = s.hierarchy_line(i + 1, line, &t)? {
            s.out.push_str(&renamed);
        } else {
            s.keep(line);
        }
    }
    s.finish(text.lines().count().max(1))
}

/// What `sanitize` has read so far.
#[derive(Default)]
struct Sanitizer {
    out: String,
    hierarchy: bool,
    root: bool,
    motion: bool,
    /// Brace depth in the hierarchy.
    depth: i64,
    /// Channels declared, frames declared, whether `Frame Time:` came, values read.
    channels: usize,
    frames: Option<usize>,
    frame_time: bool,
    values: usize,
}

impl Sanitizer {
    fn keep(&mut self, line: &str) {
        self.out.push_str(line);
        self.out.push('\n');
    }

    /// A line after MOTION: the frame count, the frame time, or values.
    fn motion_line(&mut self, n: usize, t: &[&str]) -> Result<(), (usize, String)> {
        let first = t[0];
        if first == "Frames:" || first == "Frames" {
            let v = t.iter().skip(1).find(|x| **x != ":").ok_or((n, "`Frames:` without a count".to_string()))?;
            self.frames = Some(v.parse().map_err(|_| (n, format!("`{v}` is not a frame count")))?);
        } else if first == "Frame" {
            self.frame_time = true;
        } else {
            self.values += t.len();
        }
        Ok(())
    }

    /// A line of the hierarchy, checked; a joint's line rewritten with its name (returned).
    fn hierarchy_line(&mut self, n: usize, line: &str, t: &[&str]) -> Result<Option<String>, (usize, String)> {
        let first = t[0];
        match first {
            "HIERARCHY" if self.hierarchy => return Err((n, "a second HIERARCHY".into())),
            "HIERARCHY" => self.hierarchy = true,
            "ROOT" | "JOINT" => {
                if first == "ROOT" && (!self.hierarchy || self.root) {
                    return Err((n, "ROOT must come once, after HIERARCHY".into()));
                }
                if first == "JOINT" && (!self.root || self.depth < 1) {
                    return Err((n, "JOINT outside the ROOT's braces".into()));
                }
                if t.len() < 2 {
                    return Err((n, format!("{first} without a name")));
                }
                self.root = true;
                let name = t[1..].join("_");
                let name = name.rsplit([':', '|']).next().unwrap_or(&name).to_string();
                let indent = &line[..line.len() - line.trim_start().len()];
                return Ok(Some(format!("{indent}{first} {name}\n")));
            }
            "End" if t.get(1) != Some(&"Site") => return Err((n, "`End` must be followed by `Site`".into())),
            "{" => self.depth += 1,
            "}" => {
                self.depth -= 1;
                if self.depth < 0 {
                    return Err((n, "unbalanced `}`".into()));
                }
            }
            "CHANNELS" => {
                let k: usize =
                    t.get(1).and_then(|v| v.parse().ok()).ok_or((n, "CHANNELS needs a count".to_string()))?;
                if k > 6 || k != t.len() - 2 {
                    return Err((n, format!("CHANNELS {k} lists {} channels", t.len().saturating_sub(2))));
                }
                self.channels += k;
            }
            "MOTION" => {
                if !self.root || self.depth != 0 {
                    return Err((n, "MOTION before the hierarchy is complete".into()));
                }
                self.motion = true;
            }
            _ => {}
        }
        Ok(None)
    }

    /// The text, once the motion section is complete and holds every value it declares.
    fn finish(self, end: usize) -> Result<String, (usize, String)> {
        if !self.motion {
            return Err((end, "no MOTION section".into()));
        }
        let frames = self.frames.ok_or((end, "no `Frames:` line".to_string()))?;
        if !self.frame_time {
            return Err((end, "no `Frame Time:` line".into()));
        }
        let (channels, values) = (self.channels, self.values);
        if frames.checked_mul(channels) != Some(values) {
            return Err((
                end,
                format!(
                    "{frames} frames of {channels} channels need {} values, found {values}",
                    frames.saturating_mul(channels)
                ),
            ));
        }
        Ok(self.out)
    }
}

/// What a joint name says about the body part.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointKind {
    Hips,
    /// Spine, Spine1, Chest, LowerBack …: assigned to Spine/Chest/UpperChest by chain order.
    Spine,
    Neck,
    /// Neck1, Neck2: extra neck joints, absorbed by the neighbours.
    NeckExtra,
    Head,
    Jaw,
    Bone(Side, Part),
}

/// Limb parts that exist on both sides.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    Eye,
    Shoulder,
    UpperArm,
    LowerArm,
    Hand,
    UpperLeg,
    LowerLeg,
    Foot,
    Toes,
    Finger(Finger, usize),
}

/// Classifies a joint name (case and separators ignored, namespaces like `mixamorig:` dropped).
pub fn joint_kind(name: &str) -> Option<JointKind> {
    let base = name.rsplit([':', '|']).next().unwrap_or(name).to_ascii_lowercase();
    let base = ["bip001", "bip01"]
        .iter()
        .find_map(|p| base.strip_prefix(p))
        .map_or(base.as_str(), |r| r.trim_start_matches(['_', ' ', '.']))
        .to_string();
    let clean = |s: &str| s.chars().filter(|c| c.is_ascii_alphanumeric()).collect::<String>();
    let full = clean(&base);
    match full.as_str() {
        "hips" | "hip" | "pelvis" => return Some(JointKind::Hips),
        "spine" | "spine1" | "spine2" | "spine3" | "chest" | "chest1" | "chest2" | "upperchest" | "lowerback"
        | "abdomen" | "torso" => return Some(JointKind::Spine),
        "neck" => return Some(JointKind::Neck),
        "neck1" | "neck2" => return Some(JointKind::NeckExtra),
        "head" => return Some(JointKind::Head),
        "jaw" => return Some(JointKind::Jaw),
        _ => {}
    }
    let sided = |side: Side, rest: &str| part_of(&clean(rest)).map(|p| JointKind::Bone(side, p));
    for (prefix, side) in [("left", Side::Left), ("right", Side::Right)] {
        if let Some(rest) = base.strip_prefix(prefix) {
            return sided(side, rest);
        }
    }
    for (suffixes, side) in [(["_l", ".l", "_left"], Side::Left), (["_r", ".r", "_right"], Side::Right)] {
        for s in suffixes {
            if let Some(rest) = base.strip_suffix(s) {
                return sided(side, rest);
            }
        }
    }
    for (prefix, side) in [('l', Side::Left), ('r', Side::Right)] {
        if let Some(rest) = base.strip_prefix(prefix)
            && let Some(k) = sided(side, rest.trim_start_matches(['_', '.']))
        {
            return Some(k);
        }
    }
    None
}

fn part_of(rest: &str) -> Option<Part> {
    Some(match rest {
        "eye" => Part::Eye,
        "shoulder" | "collar" | "clavicle" => Part::Shoulder,
        "arm" | "uparm" | "upperarm" | "humerus" => Part::UpperArm,
        "forearm" | "lowarm" | "lowerarm" | "elbow" => Part::LowerArm,
        "hand" | "wrist" => Part::Hand,
        "upleg" | "upperleg" | "thigh" | "femur" | "hip" => Part::UpperLeg,
        "leg" | "lowerleg" | "lowleg" | "shin" | "knee" | "calf" | "tibia" => Part::LowerLeg,
        "foot" | "ankle" => Part::Foot,
        "toebase" | "toe" | "toes" => Part::Toes,
        _ => return finger_of(rest).map(|(f, ph)| Part::Finger(f, ph)),
    })
}

fn finger_of(rest: &str) -> Option<(Finger, usize)> {
    let rest = rest.strip_prefix("hand").unwrap_or(rest);
    let (finger, tail) = [
        ("thumb", Finger::Thumb),
        ("index", Finger::Index),
        ("middle", Finger::Middle),
        ("ring", Finger::Ring),
        ("pinky", Finger::Little),
        ("little", Finger::Little),
    ]
    .into_iter()
    .find_map(|(w, f)| rest.strip_prefix(w).map(|t| (f, t)))?;
    let ph = match tail {
        "" | "1" | "proximal" => 0,
        "2" | "intermediate" => 1,
        "3" | "distal" => 2,
        _ => return None,
    };
    Some((finger, ph))
}

/// The humanoid bone a limb part names.
fn limb_bone(side: Side, part: Part) -> Bone {
    use Bone::*;
    let lr = |l: Bone, r: Bone| if side == Side::Left { l } else { r };
    match part {
        Part::Eye => lr(LeftEye, RightEye),
        Part::Shoulder => lr(LeftShoulder, RightShoulder),
        Part::UpperArm => lr(LeftUpperArm, RightUpperArm),
        Part::LowerArm => lr(LeftLowerArm, RightLowerArm),
        Part::Hand => lr(LeftHand, RightHand),
        Part::UpperLeg => lr(LeftUpperLeg, RightUpperLeg),
        Part::LowerLeg => lr(LeftLowerLeg, RightLowerLeg),
        Part::Foot => lr(LeftFoot, RightFoot),
        Part::Toes => lr(LeftToes, RightToes),
        Part::Finger(f, ph) => Bone::finger(side, f, ph),
    }
}

/// The child bone whose joint marks the end of `b` (for rest-pose alignment).
fn tip_child(b: Bone) -> Option<Bone> {
    use Bone::*;
    Some(match b {
        Hips => Spine,
        Spine => Chest,
        Chest => UpperChest,
        UpperChest => Neck,
        Neck => Head,
        LeftShoulder => LeftUpperArm,
        RightShoulder => RightUpperArm,
        LeftUpperArm => LeftLowerArm,
        RightUpperArm => RightLowerArm,
        LeftLowerArm => LeftHand,
        RightLowerArm => RightHand,
        LeftHand => LeftMiddleProximal,
        RightHand => RightMiddleProximal,
        LeftUpperLeg => LeftLowerLeg,
        RightUpperLeg => RightLowerLeg,
        LeftLowerLeg => LeftFoot,
        RightLowerLeg => RightFoot,
        LeftFoot => LeftToes,
        RightFoot => RightToes,
        _ => {
            let next = Bone::from_index(b.index() + 1)?;
            return (next.parent() == Some(b)).then_some(next);
        }
    })
}

struct Joint {
    parent: Option<usize>,
    offset: Vector3<f32>,
    end_site: Option<Vector3<f32>>,
    channels: Vec<(ChannelType, usize)>,
}

/// Retargets a parsed BVH to muscles of body `h`.
pub fn retarget(bvh: &Bvh, h: &Humanoid, file: &str) -> Result<Motion, BvhError> {
    let err = |message: String| BvhError::Skeleton { file: file.to_string(), message };
    let (joints, names) = read_joints(bvh);
    if joints.is_empty() {
        return Err(err("has no joints".into()));
    }
    if bvh.num_frames() == 0 {
        return Err(err("has no motion frames".into()));
    }
    let map = map_bones(&joints, &names);
    let mapped = map.iter().filter(|m| m.is_some()).count();
    let need = [Bone::Hips, Bone::LeftUpperArm, Bone::RightUpperArm];
    if let Some(b) = need.iter().find(|b| map[b.index()].is_none()) {
        return Err(err(format!(
            "no joint for the humanoid's {} (found {mapped} humanoid joints among {:?})",
            b.name(),
            names
        )));
    }
    // Rest positions (all rotations zero).
    let mut rest = vec![Vector3::zeros(); joints.len()];
    for (i, j) in joints.iter().enumerate() {
        rest[i] = j.parent.map_or(Vector3::zeros(), |p| rest[p]) + j.offset;
    }
    let to_ours = body_axes(&map, &rest);
    let align = alignment(&joints, &map, &rest, &to_ours, h);
    Ok(resample(bvh, &joints, &map, &align, &to_ours, h))
}

/// The file's joints (parent, offset, end site, channels) and their names.
fn read_joints(bvh: &Bvh) -> (Vec<Joint>, Vec<String>) {
    let mut joints = Vec::new();
    let mut names = Vec::new();
    for j in bvh.joints() {
        let d = j.data();
        joints.push(Joint {
            parent: if d.is_root() { None } else { d.parent_index() },
            offset: Vector3::new(d.offset().x, d.offset().y, d.offset().z),
            end_site: d.end_site().map(|e| Vector3::new(e.x, e.y, e.z)),
            channels: d.channels().iter().map(|c| (c.channel_type(), c.motion_index())).collect(),
        });
        names.push(String::from_utf8_lossy(d.name().as_ref()).into_owned());
    }
    (joints, names)
}

/// The file's body axes → ours, from its rest pose. BVH is right-handed: forward = up × right.
fn body_axes(map: &[Option<usize>; BONES], rest: &[Vector3<f32>]) -> Matrix3<f32> {
    let rest_of = |b: Bone| map[b.index()].map(|j| rest[j]);
    let up = (rest_of(Bone::Head).or(rest_of(Bone::Neck)).unwrap_or(rest[0] + Vector3::y())
        - rest_of(Bone::Hips).unwrap())
    .normalize();
    let mut right = rest_of(Bone::RightUpperArm).unwrap() - rest_of(Bone::LeftUpperArm).unwrap();
    right = (right - up * right.dot(&up)).normalize();
    let fwd = up.cross(&right);
    Matrix3::from_rows(&[right.transpose(), up.transpose(), fwd.transpose()])
}

/// Per bone: the rotation from the humanoid's T-pose direction to the file's rest direction.
fn alignment(
    joints: &[Joint],
    map: &[Option<usize>; BONES],
    rest: &[Vector3<f32>],
    to_ours: &Matrix3<f32>,
    h: &Humanoid,
) -> [UnitQuaternion<f32>; BONES] {
    let rest_of = |b: Bone| map[b.index()].map(|j| rest[j]);
    let sk = h.skeleton();
    let mut align = [UnitQuaternion::identity(); BONES];
    for b in Bone::ALL {
        let Some(j) = map[b.index()] else { continue };
        // Compare like with like: joint to the same child joint in both skeletons when the file
        // has it, else the bone's end.
        let child = tip_child(b).filter(|c| map[c.index()].is_some());
        let dir = child.and_then(rest_of).map(|c| c - rest[j]).or(joints[j].end_site).or_else(|| {
            let kids: Vec<usize> = (0..joints.len()).filter(|&k| joints[k].parent == Some(j)).collect();
            (kids.len() == 1).then(|| joints[kids[0]].offset)
        });
        if let Some(d) = dir.filter(|d| d.norm() > 1e-6) {
            let ours = child.map_or(sk.bone_def(b).tip, |c| sk.bone_def(c).offset);
            align[b.index()] =
                UnitQuaternion::rotation_between(&ours, &(*to_ours * d)).unwrap_or_else(UnitQuaternion::identity);
        }
    }

    align
}

/// The muscles at our frame rate: each of our frames between the two source frames around it.
fn resample(
    bvh: &Bvh,
    joints: &[Joint],
    map: &[Option<usize>; BONES],
    align: &[UnitQuaternion<f32>; BONES],
    to_ours: &Matrix3<f32>,
    h: &Humanoid,
) -> Motion {
    let sk = h.skeleton();
    let conv = |q: &Rotation3<f32>| Rotation3::from_matrix_unchecked(*to_ours * q.matrix() * to_ours.transpose());
    let dt = bvh.frame_time().as_secs_f32();
    let dt = if dt > 0.0 { dt } else { 1.0 / FPS };
    let n = bvh.num_frames();
    let frames: Vec<&bvh_anim::Frame> = bvh.frames().collect();
    let mut cache: Vec<Option<[f32; MUSCLES]>> = vec![None; n];
    let mut muscles_at = |k: usize| -> [f32; MUSCLES] {
        *cache[k].get_or_insert_with(|| {
            let vals = frames[k].as_slice();
            let mut global = vec![Rotation3::identity(); joints.len()];
            for (i, j) in joints.iter().enumerate() {
                let mut local = Rotation3::identity();
                for &(c, m) in &j.channels {
                    let a = vals.get(m).copied().unwrap_or(0.0).to_radians();
                    local *= match c {
                        ChannelType::RotationX => Rotation3::from_axis_angle(&Vector3::x_axis(), a),
                        ChannelType::RotationY => Rotation3::from_axis_angle(&Vector3::y_axis(), a),
                        ChannelType::RotationZ => Rotation3::from_axis_angle(&Vector3::z_axis(), a),
                        _ => Rotation3::identity(),
                    };
                }
                global[i] = j.parent.map_or(Rotation3::identity(), |p| global[p]) * local;
            }
            muscles_from_globals(sk, map, align, |j| UnitQuaternion::from_rotation_matrix(&conv(&global[j])))
        })
    };
    let mut out = Motion::constant(&STANDING);
    for t in 0..FRAMES {
        let s = (t as f32 / FPS / dt).min((n - 1) as f32);
        let k = s.floor() as usize;
        let w = s - k as f32;
        let a = muscles_at(k);
        let b = if w > 0.0 && k + 1 < n { muscles_at(k + 1) } else { a };
        let f = out.frame_mut(t);
        for i in 0..MUSCLES {
            f[i] = a[i] + (b[i] - a[i]) * w;
        }
    }
    out
}

/// Which BVH joint drives each humanoid bone.
fn map_bones(joints: &[Joint], names: &[String]) -> [Option<usize>; BONES] {
    let kinds: Vec<Option<JointKind>> = names.iter().map(|n| joint_kind(n)).collect();
    let mut map = [None; BONES];
    let first = |k: JointKind| kinds.iter().position(|x| *x == Some(k));
    map[Bone::Hips.index()] = first(JointKind::Hips).or(Some(0));
    let head = first(JointKind::Head);
    map[Bone::Head.index()] = head;
    map[Bone::Jaw.index()] = first(JointKind::Jaw);
    // Spine and neck joints between the hips and the head, in order.
    let top = head.or_else(|| first(JointKind::Neck));
    if let Some(top) = top {
        let mut chain = Vec::new();
        let mut j = joints[top].parent;
        while let Some(x) = j {
            if Some(x) == map[Bone::Hips.index()] {
                break;
            }
            chain.push(x);
            j = joints[x].parent;
        }
        chain.reverse();
        let spine: Vec<usize> = chain.iter().copied().filter(|&x| kinds[x] == Some(JointKind::Spine)).collect();
        let slots: &[Bone] = match spine.len() {
            0 => &[],
            1 => &[Bone::Spine],
            2 => &[Bone::Spine, Bone::Chest],
            _ => &[Bone::Spine, Bone::Chest, Bone::UpperChest],
        };
        for (k, b) in slots.iter().enumerate() {
            // With more than three, the last one is the upper chest.
            let x = if k == 2 { spine[spine.len() - 1] } else { spine[k] };
            map[b.index()] = Some(x);
        }
        map[Bone::Neck.index()] =
            chain.iter().copied().find(|&x| matches!(kinds[x], Some(JointKind::Neck | JointKind::NeckExtra)));
    }
    for (i, k) in kinds.iter().enumerate() {
        if let Some(JointKind::Bone(side, part)) = k {
            let b = limb_bone(*side, *part);
            map[b.index()].get_or_insert(i);
        }
    }
    map
}

/// Muscles from each mapped bone's rotation (ours, relative to the T-pose) per joint.
fn muscles_from_globals(
    sk: &Skeleton,
    map: &[Option<usize>; BONES],
    align: &[UnitQuaternion<f32>; BONES],
    global_of_joint: impl Fn(usize) -> UnitQuaternion<f32>,
) -> [f32; MUSCLES] {
    let mut m = STANDING;
    let mut global = [UnitQuaternion::identity(); BONES];
    for b in EVAL_ORDER {
        let d = sk.bone_def(b);
        let parent = d.parent.map_or(UnitQuaternion::identity(), |p| global[p.index()]);
        global[b.index()] = match map[b.index()] {
            Some(j) => global_of_joint(j) * align[b.index()],
            None => parent * d.local_rotation(&STANDING),
        };
        if d.parent.is_some() && map[b.index()].is_some() {
            let local = parent.inverse() * global[b.index()];
            decompose(d, &(d.zero.inverse() * local), &mut m);
        }
    }
    m
}

/// Splits a rotation (relative to muscle zero, in the bone's frame) into swing and twist and
/// writes the muscle values that produce it.
fn decompose(d: &BoneDef, q: &UnitQuaternion<f32>, m: &mut [f32; MUSCLES]) {
    let t_axis = d.twist.map_or(d.twist_axis, |t| t.axis);
    let v = q.imag();
    let proj = t_axis * v.dot(&t_axis);
    let twist = nalgebra::Quaternion::new(q.w, proj.x, proj.y, proj.z);
    let twist = if twist.norm() > 1e-9 { UnitQuaternion::from_quaternion(twist) } else { UnitQuaternion::identity() };
    let swing = q * twist.inverse();
    // The inverse of Unity's tan-half swing (BoneDef::local_rotation).
    let w = swing.w.abs().max(1e-6);
    let tan_half = swing.imag() * swing.w.signum() / w;
    for s in d.swing.iter().flatten() {
        let angle = 2.0 * tan_half.dot(&s.axis).atan();
        m[s.muscle] = muscle_value(s.muscle, angle.to_degrees()).clamp(-1.0, 1.0);
    }
    if let Some(t) = d.twist {
        let angle = twist.scaled_axis().dot(&t.axis);
        m[t.muscle] = muscle_value(t.muscle, angle.to_degrees()).clamp(-1.0, 1.0);
    }
}

/// The motion on `h`'s skeleton as BVH text: joints named as Unity's bones, T-pose rest,
/// centimetres, Y up, the person facing +Z, ZXY Euler rotations, 30 fps.
pub fn export(h: &Humanoid, motion: &Motion) -> String {
    use std::fmt::Write;
    let sk = h.skeleton();
    // Ours (x right) → BVH (x left): mirror x.
    let flip = |v: Vector3<f32>| Vector3::new(-v.x, v.y, v.z) * 100.0;
    let children = |b: Bone| Bone::ALL.into_iter().filter(move |c| c.parent() == Some(b));
    let mut out = String::from("HIERARCHY\n");
    fn write_joint(
        out: &mut String,
        sk: &Skeleton,
        b: Bone,
        depth: usize,
        flip: &dyn Fn(Vector3<f32>) -> Vector3<f32>,
        children: &dyn Fn(Bone) -> Vec<Bone>,
    ) {
        let pad = "  ".repeat(depth);
        let d = sk.bone_def(b);
        let o = flip(d.offset);
        if depth == 0 {
            let _ = writeln!(out, "ROOT {}\n{{\n{pad}  OFFSET {:.4} {:.4} {:.4}", b.name(), o.x, o.y, o.z);
            let _ = writeln!(out, "{pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation");
        } else {
            let _ = writeln!(out, "{pad}JOINT {}\n{pad}{{\n{pad}  OFFSET {:.4} {:.4} {:.4}", b.name(), o.x, o.y, o.z);
            let _ = writeln!(out, "{pad}  CHANNELS 3 Zrotation Xrotation Yrotation");
        }
        let kids = children(b);
        if kids.is_empty() {
            let t = flip(d.tip);
            let _ = writeln!(
                out,
                "{pad}  End Site\n{pad}  {{\n{pad}    OFFSET {:.4} {:.4} {:.4}\n{pad}  }}",
                t.x, t.y, t.z
            );
        }
        for c in kids {
            write_joint(out, sk, c, depth + 1, flip, children);
        }
        let _ = writeln!(out, "{pad}}}");
    }
    let kids = |b: Bone| children(b).collect::<Vec<_>>();
    write_joint(&mut out, sk, Bone::Hips, 0, &flip, &kids);
    let order = {
        let mut v = Vec::new();
        fn walk(b: Bone, v: &mut Vec<Bone>, kids: &dyn Fn(Bone) -> Vec<Bone>) {
            v.push(b);
            for c in kids(b) {
                walk(c, v, kids);
            }
        }
        walk(Bone::Hips, &mut v, &kids);
        v
    };
    let _ = writeln!(out, "MOTION\nFrames: {FRAMES}\nFrame Time: {:.8}", 1.0 / FPS);
    let m_flip = Matrix3::from_diagonal(&Vector3::new(-1.0, 1.0, 1.0));
    for t in 0..FRAMES {
        let muscles = motion.frame(t);
        let pose = sk.pose(muscles, Point3::origin(), 0.0);
        let mut line = Vec::with_capacity(order.len() * 3 + 3);
        let hips = flip(pose.position(Bone::Hips).coords);
        line.extend([hips.x, hips.y, hips.z]);
        for &b in &order {
            let local = sk.bone_def(b).local_rotation(muscles);
            let r = m_flip * local.to_rotation_matrix().matrix() * m_flip;
            // R = Rz(z)·Rx(x)·Ry(y).
            let x = r[(2, 1)].clamp(-1.0, 1.0).asin();
            let z = (-r[(0, 1)]).atan2(r[(1, 1)]);
            let y = (-r[(2, 0)]).atan2(r[(2, 2)]);
            line.extend([z.to_degrees(), x.to_degrees(), y.to_degrees()]);
        }
        let strs: Vec<String> = line.iter().map(|v| format!("{v:.4}")).collect();
        out.push_str(&strs.join(" "));
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::humanoid::muscles::idx;

    const RAISE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/raise_right_arm.bvh");

    #[test]
    fn names_of_common_rigs_map_to_bones() {
        let b = |n: &str| joint_kind(n);
        use JointKind::Bone as B;
        assert_eq!(b("mixamorig:LeftForeArm"), Some(B(Side::Left, Part::LowerArm)));
        assert_eq!(b("RightArm"), Some(B(Side::Right, Part::UpperArm)));
        assert_eq!(b("LeftUpLeg"), Some(B(Side::Left, Part::UpperLeg)));
        assert_eq!(b("RightLeg"), Some(B(Side::Right, Part::LowerLeg)));
        assert_eq!(b("mixamorig:RightHandIndex2"), Some(B(Side::Right, Part::Finger(Finger::Index, 1))));
        assert_eq!(b("LeftHandPinky3"), Some(B(Side::Left, Part::Finger(Finger::Little, 2))));
        assert_eq!(b("LThumb"), Some(B(Side::Left, Part::Finger(Finger::Thumb, 0))));
        assert_eq!(b("RightLittleIntermediate"), Some(B(Side::Right, Part::Finger(Finger::Little, 1))));
        assert_eq!(b("LeftLowerArm"), Some(B(Side::Left, Part::LowerArm)));
        assert_eq!(b("thigh_r"), Some(B(Side::Right, Part::UpperLeg)));
        assert_eq!(b("LeftCollar"), Some(B(Side::Left, Part::Shoulder)));
        assert_eq!(b("RightToeBase"), Some(B(Side::Right, Part::Toes)));
        assert_eq!(b("Spine1"), Some(JointKind::Spine));
        assert_eq!(b("LowerBack"), Some(JointKind::Spine));
        assert_eq!(b("Neck1"), Some(JointKind::NeckExtra));
        assert_eq!(b("LHipJoint"), None);
        assert_eq!(b("LeftFingerBase"), None);
        assert_eq!(b("LeftHandIndex4"), None);
        assert_eq!(b("Bip01_L_Thigh"), Some(B(Side::Left, Part::UpperLeg)));
        assert_eq!(b("Bip01_Pelvis"), Some(JointKind::Hips));
    }

    /// A hand-written clip: the right arm rises from the side to above the shoulder over one
    /// second while the left arm stays down.
    #[test]
    fn raising_right_arm_raises_muscle_48() {
        let m = import(Path::new(RAISE)).unwrap();
        let up = m.muscle(idx::RIGHT_ARM + idx::ARM_DOWN_UP);
        assert!((up[0] + 0.67).abs() < 0.05, "starts at the side: {}", up[0]);
        assert!(up[29] > 0.6, "ends above the shoulder: {}", up[29]);
        assert!(up.windows(2).take(29).all(|w| w[1] >= w[0] - 1e-4), "rises steadily");
        assert_eq!(up[99], up[40], "a short clip holds its last frame");
        let left = m.muscle(idx::LEFT_ARM + idx::ARM_DOWN_UP);
        assert!(left.iter().all(|v| (v + 0.67).abs() < 0.05));
        // Straight legs in the file are straight legs in muscles.
        assert!((m.frame(0)[idx::RIGHT_LEG + idx::LOWER_LEG_STRETCH] - 1.0).abs() < 0.02);
        assert!((m.frame(0)[idx::LEFT_LEG + idx::UPPER_LEG_FRONT_BACK] - 0.6).abs() < 0.02);
    }

    /// Export a synthesized gesture as BVH and import it again: the muscles come back.
    #[test]
    fn export_import_round_trip() {
        let h = Humanoid::default();
        let (motion, _) = crate::gesture::referencing(11, Point3::origin(), 30.0, Point3::new(1.5, 0.8, 2.0));
        let text = export(&h, &motion);
        let back = import_bytes(text.as_bytes(), "exported.bvh").unwrap();
        let mut worst = (0.0f32, 0, 0);
        for t in 0..FRAMES {
            for i in 0..MUSCLES {
                let e = (motion.frame(t)[i] - back.frame(t)[i]).abs();
                if e > worst.0 {
                    worst = (e, t, i);
                }
            }
        }
        assert!(
            worst.0 < 0.01,
            "muscle {} ({}) frame {} off by {}",
            worst.2,
            crate::humanoid::MUSCLE_NAMES[worst.2],
            worst.1,
            worst.0
        );
        let mixamo = text.replace("JOINT ", "JOINT mixamorig:").replace("ROOT ", "ROOT mixamorig:");
        let again = import_bytes(mixamo.as_bytes(), "m.bvh").unwrap();
        assert!((again.frame(50)[48] - back.frame(50)[48]).abs() < 1e-4);
    }

    #[test]
    fn bad_files_are_named() {
        let e = import_bytes(b"HIERARCHY\nROOT Hips\n{\n OFFSET 0 0\n", "broken.bvh").unwrap_err().to_string();
        assert!(e.starts_with("broken.bvh:"), "{e}");
        // Inputs the parser would panic on, or allocate the declared size for, are refused.
        let good = std::fs::read_to_string(RAISE).unwrap();
        for (bad, what) in [
            (good.replacen("HIERARCHY", "HIERARCHY\nHIERARCHY", 1), "line 2: a second HIERARCHY"),
            (good.replacen("JOINT Spine", "JOINT", 1), "line 6: JOINT without a name"),
            (good.replacen("End Site", "End Zone", 1), "`End` must be followed by `Site`"),
            (good.replacen("Frames: 31", "Frames: 4000000000000", 1), "need"),
            (
                good.replacen("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 99999999999 Zrotation", 1),
                "CHANNELS",
            ),
            (good.replacen("0.00 96.00", "0.00 x96", 1), "line 4: not a readable BVH"),
        ] {
            let e = import_bytes(bad.as_bytes(), "bad.bvh").unwrap_err().to_string();
            assert!(e.starts_with("bad.bvh: ") && e.contains(what), "{what}: {e}");
        }
        let e = import(Path::new("/nonexistent.bvh")).unwrap_err().to_string();
        assert!(e.starts_with("/nonexistent.bvh: cannot read"), "{e}");
        let lone = "HIERARCHY\nROOT Box\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  End Site\n  {\n    OFFSET 0 1 0\n  }\n}\nMOTION\nFrames: 1\nFrame Time: 0.033333\n0 0 0\n";
        let e = import_bytes(lone.as_bytes(), "box.bvh").unwrap_err().to_string();
        assert!(e.starts_with("box.bvh: no joint for the humanoid's LeftUpperArm"), "{e}");
    }
}
