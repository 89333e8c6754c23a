"""Body and hand landmarks of every frame of a video, a folder of images or a camera, by
MediaPipe Holistic (its models ship in the mediapipe 0.10.14 wheel: no download at run time).

    python3 landmarks.py SOURCE OUT.jsonl [--fps F] [--seconds S]
    python3 landmarks.py - -        (a stream: `orchestrator live`'s webcam frames)

Writes one JSON object a line: first {"source", "fps", "width", "height"}, then per frame
{"t": seconds, "pose": 33 x [x, y, z, visibility] (world metres, x right, y down, z away from
the camera, origin between the hips) or null, "left_hand" / "right_hand": 21 x [x, y, z] of the
person's own hand (pixels; z at x's scale) or null, "pose_image": the 33 pose landmarks in the
image, [x, y] pixels, or null}. Progress goes to stderr; a source that
cannot be read ends with one "[error] ..." line on stderr and exit status 2 (3: mediapipe
missing).

With SOURCE and OUT both "-", images arrive on stdin, each after its length (4 bytes, little
endian), and each is answered at once by its landmark line on stdout (no first line; "t" is 0,
the caller keeps the time; an image that cannot be decoded is answered with nulls and an
"error"). The model then keeps its tracking from frame to frame, as with a video.
"""

import argparse
import glob
import itertools
import json
import os
import sys


def fail(message, status=2):
    # the one line the orchestrator reports (MediaPipe's own logs go to stderr too)
    print("[error] " + message, file=sys.stderr, flush=True)
    sys.exit(status)


def frames(source, fps, seconds, cv2):
    """Yields (seconds, BGR image) and sets frames.fps."""
    if os.path.isdir(source):
        files = sorted(f for e in ("png", "jpg", "jpeg") for f in glob.glob(os.path.join(source, "*." + e)))
        if not files:
            fail("no .png or .jpg images in the folder")
        frames.fps = fps or 30.0
        for i, f in enumerate(files):
            img = cv2.imread(f)
            if img is None:
                fail(f"{os.path.basename(f)}: not an image")
            yield i / frames.fps, img
        return
    camera = source.isdigit()
    if not camera and not os.path.isfile(source):
        fail("no such file")
    cap = cv2.VideoCapture(int(source) if camera else source)
    if not cap.isOpened():
        fail("cannot be opened as a video" if not camera else "no camera with this index")
    frames.fps = fps or cap.get(cv2.CAP_PROP_FPS) or 30.0
    limit = seconds if camera else None
    i = 0
    while True:
        ok, img = cap.read()
        if not ok:
            break
        t = i / frames.fps
        if limit is not None and t >= limit:
            break
        yield t, img
        i += 1
    cap.release()


def landmarks(holistic, cv2, img, t):
    """One frame's landmark row."""
    h, w = img.shape[:2]
    r = holistic.process(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    pose = pose_image = None
    if r.pose_world_landmarks is not None:
        pose = [[l.x, l.y, l.z, l.visibility] for l in r.pose_world_landmarks.landmark]
    if r.pose_landmarks is not None:
        pose_image = [[l.x * w, l.y * h] for l in r.pose_landmarks.landmark]

    def hand(lms):
        return None if lms is None else [[l.x * w, l.y * h, l.z * w] for l in lms.landmark]

    return {
        "t": t,
        "pose": pose,
        "left_hand": hand(r.left_hand_landmarks),
        "right_hand": hand(r.right_hand_landmarks),
        "pose_image": pose_image,
    }


def stream(mp, cv2):
    """Answers each image on stdin with its landmark line on stdout, until stdin closes."""
    import numpy as np

    holistic = mp.solutions.holistic.Holistic(
        static_image_mode=False, model_complexity=1, smooth_landmarks=True, refine_face_landmarks=False
    )
    src, out = sys.stdin.buffer, sys.stdout
    while True:
        head = src.read(4)
        if len(head) < 4:
            return
        data = src.read(int.from_bytes(head, "little"))
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if data else None
        if img is None:
            row = {"t": 0.0, "pose": None, "left_hand": None, "right_hand": None, "error": "not an image"}
        else:
            row = landmarks(holistic, cv2, img, 0.0)
        out.write(json.dumps(row) + "\n")
        out.flush()


def main():
    p = argparse.ArgumentParser()
    p.add_argument("source")
    p.add_argument("out")
    p.add_argument("--fps", type=float, default=0.0)
    p.add_argument("--seconds", type=float, default=6.0)
    a = p.parse_args()
    try:
        import cv2
        import mediapipe as mp
    except ImportError as e:
        fail(f"mediapipe is not installed ({e}); scripts/setup.sh installs it", 3)
    if a.source == "-" and a.out == "-":
        return stream(mp, cv2)

    images = frames(a.source, a.fps, a.seconds, cv2)
    first = next(images, None)  # a source that cannot be read fails before the model loads
    if first is None:
        fail("has no frames")
    holistic = mp.solutions.holistic.Holistic(
        static_image_mode=False, model_complexity=1, smooth_landmarks=True, refine_face_landmarks=False
    )
    n = 0
    with open(a.out, "w") as out:
        for t, img in itertools.chain([first], images):
            h, w = img.shape[:2]
            if n == 0:
                out.write(json.dumps({"source": a.source, "fps": frames.fps, "width": w, "height": h}) + "\n")
            out.write(json.dumps(landmarks(holistic, cv2, img, t)) + "\n")
            n += 1
            if n % 30 == 0:
                print(f"[capture] {n} frames ({t:.1f} s) read", file=sys.stderr, flush=True)


if __name__ == "__main__":
    main()
