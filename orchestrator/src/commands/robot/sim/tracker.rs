//! The body tracker the simulator plays for `--gesture skeleton`: its person's 18 REP-155
//! keypoints (OpenPose's COCO order) where the camera sees them. A keypoint off the image is not
//! found; one behind something nearer (the depth image says so) is found unsure, as a tracker
//! guesses a hidden joint.

use nalgebra::{Point3, Vector3};

use worker::camera::{Camera, Intrinsics, decode_depth};
use worker::humanoid::{Bone, SkeletonPose};

use crate::commands::robot::msgs::NormalizedPoint;

/// The person's one id in the tracker's lists.
pub const BODY: &str = "person";

/// How sure the tracker is of a joint it sees, and of one hidden behind something.
const SEEN: f32 = 0.95;
const HIDDEN: f32 = 0.3;

/// How much nearer than a joint the depth may be before the joint counts as hidden (m): a
/// joint lies inside the body, its hips and shoulders a hand's width behind the skin.
const HIDDEN_BY: f32 = 0.25;

/// The keypoints' places in the world (COCO order): the joints of the skeleton's bones, and the
/// face's from its eyes (nose before them, ears behind them on either side).
fn keypoints(p: &SkeletonPose) -> [Point3<f32>; 18] {
    let (le, re) = (p.position(Bone::LeftEye), p.position(Bone::RightEye));
    let eyes = Point3::from((le.coords + re.coords) / 2.0);
    let (ahead, left, up) = (p.head_forward(), (le - re).normalize(), Vector3::y());
    let nose = eyes + ahead * 0.03 - up * 0.04;
    let ear = |side: f32| eyes - ahead * 0.09 + left * (0.075 * side);
    let (ls, rs) = (p.position(Bone::LeftUpperArm), p.position(Bone::RightUpperArm));
    [
        nose,
        Point3::from((ls.coords + rs.coords) / 2.0),
        rs,
        p.position(Bone::RightLowerArm),
        p.position(Bone::RightHand),
        ls,
        p.position(Bone::LeftLowerArm),
        p.position(Bone::LeftHand),
        p.position(Bone::RightUpperLeg),
        p.position(Bone::RightLowerLeg),
        p.position(Bone::RightFoot),
        p.position(Bone::LeftUpperLeg),
        p.position(Bone::LeftLowerLeg),
        p.position(Bone::LeftFoot),
        le,
        re,
        ear(1.0),
        ear(-1.0),
    ]
}

/// The person's keypoints in the image of `camera`, whose depth buffer is `depth` (row-major,
/// `k.width × k.height`, as the renderer encodes it); `None` when too few are seen to track them.
pub fn body(p: &SkeletonPose, camera: &Camera, k: &Intrinsics, depth: &[u16]) -> Option<[NormalizedPoint; 18]> {
    let (w, h) = (k.width as f32, k.height as f32);
    let points = keypoints(p).map(|q| {
        let Some((x, y, z)) = camera.project(k, &q).filter(|&(x, y, _)| x >= 0.0 && y >= 0.0 && x < w && y < h) else {
            return NormalizedPoint::default();
        };
        let at = y as usize * k.width as usize + x as usize;
        let nearer = depth.get(at).map(|&d| decode_depth(d)).is_some_and(|d| d > 0.0 && d < z - HIDDEN_BY);
        NormalizedPoint { x: x / w, y: y / h, c: if nearer { HIDDEN } else { SEEN } }
    });
    // a tracker follows a body once a few of its joints show
    (points.iter().filter(|q| q.c == SEEN).count() >= 4).then_some(points)
}

#[cfg(test)]
mod tests {
    use super::*;
    use worker::humanoid::Humanoid;

    #[test]
    fn a_person_before_the_camera_is_tracked_their_left_on_the_images_right() {
        let pose = Humanoid::seeded(0).pose(&[0.0; worker::humanoid::MUSCLES], Point3::new(0.0, 0.0, 2.5), 180.0);
        let camera = Camera::new(Point3::new(0.0, 0.6, 0.0), 0.0);
        let k = Intrinsics { width: 640, height: 480, fov_deg: 90.0 };
        let far = vec![u16::MAX; 640 * 480];
        let b = body(&pose, &camera, &k, &far).expect("tracked");
        // facing the camera: their left shoulder (5) and hip (11) on the image's right
        assert!(b[5].x > b[2].x && b[11].x > b[8].x, "{b:?}");
        // the head above the shoulders, the hips below
        assert!(b[0].y < b[1].y && b[8].y > b[2].y, "{b:?}");
        assert!(b.iter().all(|q| q.c == SEEN), "{b:?}");
        // a wall 1 m ahead hides every joint; turned away from the person, nothing is tracked
        let wall = vec![worker::camera::encode_depth(1.0); 640 * 480];
        assert!(body(&pose, &camera, &k, &wall).is_none());
        assert!(body(&pose, &Camera::new(Point3::new(0.0, 0.6, 0.0), 180.0), &k, &far).is_none());
    }
}
