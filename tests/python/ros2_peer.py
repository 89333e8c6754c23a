"""A ROS 2 robot spoken by another DDS implementation (Eclipse Cyclone DDS), for the interop
test of `orchestrator robot`: ROS 2's topic names (`rt/...`) and types
(`sensor_msgs::msg::dds_::Image_`), written here from their .msg definitions.

It publishes a recorded camera frame (colour rgb8 and 16UC1 depth, 640x480, with camera_info),
odometry at 30 Hz integrating the node's cmd_vel, and the person's gesture; sends a goal; and
goes through phases: good input (the node must drive), an image of another encoding, no camera,
a gesture that is not of its type, then good input again. It prints one JSON line of what it
saw in each phase.

    python3 ros2_peer.py --domain 42 --frames DIR --seconds 6
"""

import argparse
import json
import math
import time
from dataclasses import dataclass

import numpy as np
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.annotations import final
from cyclonedds.idl.types import array, float32, float64, int32, sequence, uint8, uint16, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic


@dataclass
@final
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
@final
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
@final
class Image(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    header: Header
    height: uint32
    width: uint32
    encoding: str
    is_bigendian: uint8
    step: uint32
    data: sequence[uint8]


@dataclass
@final
class RegionOfInterest(IdlStruct, typename="sensor_msgs::msg::dds_::RegionOfInterest_"):
    x_offset: uint32
    y_offset: uint32
    height: uint32
    width: uint32
    do_rectify: bool


@dataclass
@final
class CameraInfo(IdlStruct, typename="sensor_msgs::msg::dds_::CameraInfo_"):
    header: Header
    height: uint32
    width: uint32
    distortion_model: str
    d: sequence[float64]
    k: array[float64, 9]
    r: array[float64, 9]
    p: array[float64, 12]
    binning_x: uint32
    binning_y: uint32
    roi: RegionOfInterest


@dataclass
@final
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
@final
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@dataclass
@final
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
@final
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
@final
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
@final
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3


@dataclass
@final
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist
    covariance: array[float64, 36]


@dataclass
@final
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance


@dataclass
@final
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str


@dataclass
@final
class Gesture(IdlStruct, typename="gesthor_msgs::msg::dds_::Gesture_"):
    header: Header
    kind: uint8
    person: Pose
    frames: uint16
    dims: uint16
    muscles: sequence[float32]


@dataclass
@final
class NotAGesture(IdlStruct, typename="gesthor_msgs::msg::dds_::Gesture_"):
    """Gesture's type name over a header alone: a robot built with other gesthor_msgs."""
    header: Header


@dataclass
@final
class Decision(IdlStruct, typename="gesthor_msgs::msg::dds_::Decision_"):
    header: Header
    episode: uint32
    step: uint32
    action: uint8
    action_name: str
    probs: sequence[float32]
    value: float32
    gesture_kind: uint8
    gesture_source: str
    done: bool
    holding: str


def stamp(t):
    return Time(sec=int(t), nanosec=int((t - int(t)) * 1e9))


def planar(x, y, yaw):
    return Pose(position=Point(x=x, y=y, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--frames", required=True, help="folder of rgb.bin (640x480x3), depth.bin (u16 mm), gesture.bin (f32), meta.json")
    ap.add_argument("--seconds", type=float, default=6.0, help="each phase's length")
    a = ap.parse_args()
    meta = json.load(open(f"{a.frames}/meta.json"))
    w, h = meta["width"], meta["height"]
    rgb = np.fromfile(f"{a.frames}/rgb.bin", dtype=np.uint8)
    depth = np.fromfile(f"{a.frames}/depth.bin", dtype=np.uint16)
    muscles = np.fromfile(f"{a.frames}/gesture.bin", dtype=np.float32)

    dp = DomainParticipant(a.domain)
    reliable = Qos(Policy.Reliability.Reliable(max_blocking_time=1_000_000_000), Policy.History.KeepLast(10))
    writer = lambda name, t: DataWriter(dp, Topic(dp, name, t), qos=reliable)
    colour_w = writer("rt/camera/color/image_raw", Image)
    depth_w = writer("rt/camera/aligned_depth_to_color/image_raw", Image)
    info_w = writer("rt/camera/color/camera_info", CameraInfo)
    odom_w = writer("rt/odom", Odometry)
    gesture_w = writer("rt/gesthor/gesture", Gesture)
    not_a_gesture_w = writer("rt/gesthor/gesture", NotAGesture)
    goal_w = writer("rt/gesthor_robot/goal", String)
    cmd_r = DataReader(dp, Topic(dp, "rt/cmd_vel", Twist), qos=reliable)
    decision_r = DataReader(dp, Topic(dp, "rt/gesthor_robot/decision", Decision), qos=reliable)

    f = h / 2 / math.tan(math.radians(meta["fov_deg"]) / 2)
    cx, cy = (w - 1) / 2, (h - 1) / 2
    x = y = yaw = 0.0
    v = wz = 0.0
    phases = ["good", "mono8", "no_camera", "garbled", "good_again"]
    # per phase: decisions taken, commands heard, why the node held still, and moving commands
    # heard after it said it holds (there must be none)
    seen = {p: {"decisions": 0, "moving_commands": 0, "zero_commands": 0, "holding": [], "moving_after_hold": 0} for p in phases}
    start = time.time()
    # wait for the node's goal reader (a sample before it would be lost)
    while goal_w.get_publication_matched_status().current_count == 0:
        if time.time() - start > 60:
            raise SystemExit("no orchestrator robot subscribed to rt/gesthor_robot/goal in 60 s")
        time.sleep(0.05)
    time.sleep(0.5)
    goal_sent = False
    t0 = time.time()
    next_frame = t0
    while True:
        now = time.time()
        i = int((now - t0) / a.seconds)
        if i >= len(phases):
            break
        phase = phases[i]
        x += v * math.cos(yaw) / 30
        y += v * math.sin(yaw) / 30
        yaw += wz / 30
        hd = Header(stamp=stamp(now), frame_id="odom")
        odom_w.write(Odometry(header=hd, child_frame_id="base_link",
                              pose=PoseWithCovariance(pose=planar(x, y, yaw), covariance=[0.0] * 36),
                              twist=TwistWithCovariance(twist=Twist(linear=Vector3(x=v, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=wz)), covariance=[0.0] * 36)))
        if now >= next_frame and phase != "no_camera":
            ch = Header(stamp=stamp(now), frame_id="camera_color_optical_frame")
            info_w.write(CameraInfo(header=ch, height=h, width=w, distortion_model="plumb_bob", d=[0.0] * 5,
                                    k=[f, 0, cx, 0, f, cy, 0, 0, 1], r=[1, 0, 0, 0, 1, 0, 0, 0, 1],
                                    p=[f, 0, cx, 0, 0, f, cy, 0, 0, 0, 1, 0], binning_x=0, binning_y=0,
                                    roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)))
            depth_w.write(Image(header=ch, height=h, width=w, encoding="16UC1", is_bigendian=0, step=w * 2, data=depth.view(np.uint8).tobytes()))
            gh = Header(stamp=stamp(now), frame_id="odom")
            if phase == "garbled":
                not_a_gesture_w.write(NotAGesture(header=gh))
            else:
                gesture_w.write(Gesture(header=gh, kind=1, person=planar(*meta["person"]), frames=100, dims=95,
                                        muscles=muscles.tolist()))
            if phase == "mono8":
                colour_w.write(Image(header=ch, height=h, width=w, encoding="mono8", is_bigendian=0, step=w, data=rgb[::3].tobytes()))
            else:
                colour_w.write(Image(header=ch, height=h, width=w, encoding="rgb8", is_bigendian=0, step=w * 3, data=rgb.tobytes()))
            next_frame = now + 0.2
            if not goal_sent:
                goal_w.write(String(data=meta["target"]))
                goal_sent = True
        for t in cmd_r.take(N=100):
            v, wz = t.linear.x, t.angular.z
            moving = v != 0 or wz != 0
            seen[phase]["moving_commands" if moving else "zero_commands"] += 1
            if moving and seen[phase]["holding"]:
                seen[phase]["moving_after_hold"] += 1
        for d in decision_r.take(N=100):
            if d.action != 255:
                seen[phase]["decisions"] += 1
                if d.done:
                    goal_w.write(String(data=meta["target"]))
            elif d.holding:
                seen[phase]["holding"].append(d.holding)
        time.sleep(max(0.0, 1 / 30 - (time.time() - now)))
    print(json.dumps(seen))


if __name__ == "__main__":
    main()
