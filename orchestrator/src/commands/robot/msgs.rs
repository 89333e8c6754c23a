//! The ROS 2 messages the robot speaks, as serde structs in their CDR field order: ROS's own
//! (`sensor_msgs`, `nav_msgs`, `geometry_msgs`, `rosgraph_msgs`), REP-155's bodies (`hri_msgs`)
//! and the two of `gesthor_msgs`
//! (`docs/ros/gesthor_msgs/msg/*.msg`, for nodes that want to read them).

use ros2_client::builtin_interfaces::Time;
use ros2_client::{Message, MessageTypeName};
use serde::de::{self, SeqAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// A ROS type by package and name (`sensor_msgs/Image`).
pub trait Typed {
    const PACKAGE: &'static str;
    const NAME: &'static str;
    fn type_name() -> MessageTypeName {
        MessageTypeName::new(Self::PACKAGE, Self::NAME)
    }
}

macro_rules! ros_type {
    ($t:ty, $pkg:literal, $name:literal) => {
        impl Message for $t {}
        impl Typed for $t {
            const PACKAGE: &'static str = $pkg;
            const NAME: &'static str = $name;
        }
    };
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

impl Header {
    pub fn new(stamp: Time, frame_id: &str) -> Header {
        Header { stamp, frame_id: frame_id.to_string() }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub encoding: String,
    pub is_bigendian: u8,
    pub step: u32,
    #[serde(with = "serde_bytes_vec")]
    pub data: Vec<u8>,
}
ros_type!(Image, "sensor_msgs", "Image");

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct RegionOfInterest {
    pub x_offset: u32,
    pub y_offset: u32,
    pub height: u32,
    pub width: u32,
    pub do_rectify: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CameraInfo {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub distortion_model: String,
    pub d: Vec<f64>,
    pub k: [f64; 9],
    pub r: [f64; 9],
    pub p: [f64; 12],
    pub binning_x: u32,
    pub binning_y: u32,
    pub roi: RegionOfInterest,
}
ros_type!(CameraInfo, "sensor_msgs", "CameraInfo");

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub position: Vector3,
    pub orientation: Quaternion,
}

impl Pose {
    /// A pose on the floor: x, y (m) and yaw (rad, counter-clockwise from +x).
    pub fn planar(x: f64, y: f64, yaw: f64) -> Pose {
        let (s, c) = (yaw / 2.0).sin_cos();
        Pose { position: Vector3 { x, y, z: 0.0 }, orientation: Quaternion { x: 0.0, y: 0.0, z: s, w: c } }
    }

    /// x, y and the yaw about +z (the rest of the rotation is dropped).
    pub fn to_planar(&self) -> (f64, f64, f64) {
        let q = &self.orientation;
        let yaw = (2.0 * (q.w * q.z + q.x * q.y)).atan2(1.0 - 2.0 * (q.y * q.y + q.z * q.z));
        (self.position.x, self.position.y, yaw)
    }
}

/// A 6 × 6 covariance: a fixed array on the wire (no length), longer than serde's arrays.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Covariance(pub [f64; 36]);

impl Default for Covariance {
    fn default() -> Self {
        Covariance([0.0; 36])
    }
}

impl Serialize for Covariance {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple;
        let mut t = s.serialize_tuple(36)?;
        for v in &self.0 {
            t.serialize_element(v)?;
        }
        t.end()
    }
}

impl<'de> Deserialize<'de> for Covariance {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Covariance;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("36 doubles")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Covariance, A::Error> {
                let mut c = [0.0; 36];
                for (i, v) in c.iter_mut().enumerate() {
                    *v = seq.next_element()?.ok_or_else(|| de::Error::invalid_length(i, &self))?;
                }
                Ok(Covariance(c))
            }
        }
        d.deserialize_tuple(36, V)
    }
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}
ros_type!(Twist, "geometry_msgs", "Twist");

impl Twist {
    /// Forward speed (m/s) and turn rate (rad/s, counter-clockwise).
    pub fn planar(v: f64, w: f64) -> Twist {
        Twist { linear: Vector3 { x: v, ..Default::default() }, angular: Vector3 { z: w, ..Default::default() } }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TwistStamped {
    pub header: Header,
    pub twist: Twist,
}
ros_type!(TwistStamped, "geometry_msgs", "TwistStamped");

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    pub covariance: Covariance,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    pub twist: Twist,
    pub covariance: Covariance,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}
ros_type!(Odometry, "nav_msgs", "Odometry");

#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct Clock {
    pub clock: Time,
}
ros_type!(Clock, "rosgraph_msgs", "Clock");

/// `std_msgs/String` (a struct of one string is that string on the wire).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Text {
    pub data: String,
}
ros_type!(Text, "std_msgs", "String");

/// `gesthor_msgs/Gesture`: the gesture a person shows the robot now, and where they stand.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Gesture {
    /// The stamp of the camera frame it goes with; `frame_id` is the frame of `person`.
    pub header: Header,
    /// `shm_schema::gesture_kind`: 0 none, 1 referencing, 2 intervention.
    pub kind: u8,
    pub person: Pose,
    /// `frames × dims` muscle values, frame-major (GOND's 100 × 95); empty when none is shown.
    pub frames: u16,
    pub dims: u16,
    pub muscles: Vec<f32>,
}
ros_type!(Gesture, "gesthor_msgs", "Gesture");

/// `gesthor_msgs/Decision`: what the policy decided at a step, and why the robot holds still
/// when it does.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Decision {
    pub header: Header,
    /// The episode (its goal's count since the node started) and the step within it.
    pub episode: u32,
    pub step: u32,
    /// `shm_schema::action`, and its name; 255 / "" while holding still.
    pub action: u8,
    pub action_name: String,
    pub probs: Vec<f32>,
    pub value: f32,
    /// The gesture the policy was shown (0 none, 1 referencing, 2 intervention) and from where
    /// (`topic`, `camera`).
    pub gesture_kind: u8,
    pub gesture_source: String,
    /// The episode ended with this decision (a Stop, or the step limit).
    pub done: bool,
    /// Why the robot holds still, when it does; empty otherwise.
    pub holding: String,
}
ros_type!(Decision, "gesthor_msgs", "Decision");

/// `hri_msgs/NormalizedPointOfInterest2D`: a point of the image (x right, y down, each in
/// [0, 1] of its width and height) and how sure the tracker is of it (0: not found).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NormalizedPoint {
    pub x: f32,
    pub y: f32,
    pub c: f32,
}

/// `hri_msgs/Skeleton2D` (REP-155): a body's 18 keypoints in OpenPose's COCO order, stamped as
/// the image they were found in. A fixed array: no length on the wire.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Skeleton2D {
    pub header: Header,
    pub skeleton: [NormalizedPoint; 18],
}
ros_type!(Skeleton2D, "hri_msgs", "Skeleton2D");

/// `hri_msgs/IdsList`: the bodies a tracker follows in the image of the header's stamp.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct IdsList {
    pub header: Header,
    pub ids: Vec<String>,
}
ros_type!(IdsList, "hri_msgs", "IdsList");

impl Default for Header {
    fn default() -> Self {
        Header { stamp: Time::ZERO, frame_id: String::new() }
    }
}

/// `Vec<u8>` as one block of bytes (a CDR `sequence<octet>`), not byte by byte.
mod serde_bytes_vec {
    use serde::{Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &[u8], s: S) -> Result<S::Ok, S::Error> {
        s.serialize_bytes(v)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<u8>, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = Vec<u8>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("bytes")
            }
            fn visit_bytes<E>(self, v: &[u8]) -> Result<Vec<u8>, E> {
                Ok(v.to_vec())
            }
            fn visit_byte_buf<E>(self, v: Vec<u8>) -> Result<Vec<u8>, E> {
                Ok(v)
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<u8>, A::Error> {
                let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0));
                while let Some(b) = seq.next_element()? {
                    out.push(b);
                }
                Ok(out)
            }
        }
        d.deserialize_bytes(V)
    }
}
