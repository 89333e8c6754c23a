//! The person in front of their webcam: each JPEG frame the page sends goes through the landmark
//! model (`gesture/landmarks.py` in its stream mode, the same script `gesture capture` runs),
//! and from the landmarks come a wave (the call for an intervention) and, on request, a gesture
//! captured into the 95 muscles (`super::gesture`), as `gesture capture` does.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, ChildStdout, Stdio};
use std::time::Instant;

use anyhow::Context;
use serde::Deserialize;

use worker::gesture::capture::LandmarkFrame;

/// A frame larger than this is refused (a 640×480 JPEG at quality 90 is ≈ 80 KiB).
pub const MAX_FRAME_BYTES: usize = 512 * 1024;
/// How much of the recent past a wave is read from: the last second and a half, or the last
/// [`WAVE_FRAMES`] frames where fewer were read in that time (a slow machine reads a wave over a
/// longer past rather than never).
const WAVE_WINDOW: f32 = 1.5;
const WAVE_FRAMES: usize = 6;

/// Why a webcam frame was refused, in the words the page shows; `None`: it may be read. (One
/// sent before the last was answered is refused by the socket, `super::server`.)
pub fn refusal(jpeg: &[u8]) -> Option<String> {
    if jpeg.len() > MAX_FRAME_BYTES {
        return Some(format!("a webcam frame of {} bytes was refused: at most {MAX_FRAME_BYTES}", jpeg.len()));
    }
    if !jpeg.starts_with(&[0xFF, 0xD8, 0xFF]) {
        return Some("a webcam frame was refused: it is not a JPEG".into());
    }
    None
}

#[derive(Deserialize)]
struct Line {
    #[serde(flatten)]
    frame: LandmarkFrame,
    error: Option<String>,
}

/// The landmark model running on a session's frames.
pub struct Webcam {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    script: PathBuf,
    started: Instant,
    /// The frames a wave is read from ([`remember`]).
    recent: Vec<LandmarkFrame>,
    /// A capture under way: until when, and its frames.
    capturing: Option<(f32, Vec<LandmarkFrame>)>,
}

impl Webcam {
    pub fn start() -> anyhow::Result<Webcam> {
        let (mut cmd, script) = crate::commands::gesture::landmark_command()?;
        let mut child = cmd
            .args(["-", "-"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .context("starting the landmark model (GESTHOR_CAPTURE_PYTHON)")?;
        let stdin = child.stdin.take().expect("piped");
        let stdout = BufReader::new(child.stdout.take().expect("piped"));
        Ok(Webcam { child, stdin, stdout, script, started: Instant::now(), recent: Vec::new(), capturing: None })
    }

    /// The landmarks of one JPEG frame, timed from the webcam's start.
    pub fn read(&mut self, jpeg: &[u8], now: Instant) -> anyhow::Result<LandmarkFrame> {
        self.stdin.write_all(&(jpeg.len() as u32).to_le_bytes())?;
        self.stdin.write_all(jpeg)?;
        self.stdin.flush()?;
        let mut line = String::new();
        anyhow::ensure!(self.stdout.read_line(&mut line)? > 0, "the landmark model stopped (is mediapipe installed?)");
        let Line { mut frame, error } = serde_json::from_str(&line).context("the landmark model's answer")?;
        if let Some(e) = error {
            anyhow::bail!("a webcam frame was refused: {e}");
        }
        frame.t = now.duration_since(self.started).as_secs_f32();
        remember(&mut self.recent, frame.clone());
        if let Some((_, frames)) = &mut self.capturing {
            frames.push(frame.clone());
        }
        Ok(frame)
    }

    /// Whether the person is waving now.
    pub fn waving(&self) -> bool {
        waving(&self.recent)
    }

    /// Starts collecting the next `seconds` of frames for a gesture.
    pub fn start_capture(&mut self, seconds: f32) {
        let now = self.started.elapsed().as_secs_f32();
        self.capturing = Some((now + seconds, Vec::new()));
    }

    pub fn capturing(&self) -> bool {
        self.capturing.is_some()
    }

    /// The frames of a capture once its time is up.
    pub fn captured(&mut self) -> Option<Vec<LandmarkFrame>> {
        let until = self.capturing.as_ref()?.0;
        if self.started.elapsed().as_secs_f32() < until {
            return None;
        }
        self.capturing.take().map(|(_, f)| f)
    }
}

impl Drop for Webcam {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_file(&self.script);
    }
}

/// Adds `frame` to the `recent` frames a wave is read from, forgetting those older than
/// [`WAVE_WINDOW`] beyond the last [`WAVE_FRAMES`].
pub fn remember(recent: &mut Vec<LandmarkFrame>, frame: LandmarkFrame) {
    let now = frame.t;
    recent.push(frame);
    let in_window = recent.iter().filter(|f| f.t > now - WAVE_WINDOW).count();
    let forget = recent.len() - in_window.max(WAVE_FRAMES).min(recent.len());
    recent.drain(..forget);
}

/// MediaPipe's pose landmarks of the shoulders and wrists (left, right).
const SHOULDERS: [usize; 2] = [11, 12];
const WRISTS: [usize; 2] = [15, 16];

/// A wave: a hand held above its shoulder, swinging sideways at least twice by 8 cm or more,
/// in the frames given (those [`remember`] keeps). A pointing arm holds still; a raised hand
/// that does not swing is not a wave.
pub fn waving(frames: &[LandmarkFrame]) -> bool {
    (0..2).any(|side| {
        let xs: Vec<f32> = frames
            .iter()
            .filter_map(|f| {
                let p = f.pose.as_ref()?;
                let (s, w) = (p[SHOULDERS[side]], p[WRISTS[side]]);
                // y points down: a raised wrist has the smaller y
                (w[1] < s[1] - 0.05 && w[3] > 0.5).then_some(w[0] - s[0])
            })
            .collect();
        if xs.len() < 4 || xs.len() * 3 < frames.len() * 2 {
            return false;
        }
        // turns of the swing, each at least 8 cm from the last extreme
        let (mut turns, mut extreme, mut dir) = (0, xs[0], 0.0f32);
        for &x in &xs[1..] {
            let d = x - extreme;
            if dir == 0.0 {
                if d.abs() >= 0.08 {
                    dir = d.signum();
                    extreme = x;
                }
            } else if d * dir > 0.0 {
                extreme = x;
            } else if d.abs() >= 0.08 {
                turns += 1;
                dir = -dir;
                extreme = x;
            }
        }
        turns >= 2
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(t: f32, wrist_x: f32, wrist_y: f32) -> LandmarkFrame {
        let mut pose = vec![[0.0, 0.0, 0.0, 1.0]; 33];
        pose[11] = [0.15, -0.45, 0.0, 1.0];
        pose[12] = [-0.15, -0.45, 0.0, 1.0];
        pose[15] = [0.2, 0.0, 0.0, 1.0];
        pose[16] = [-0.15 + wrist_x, wrist_y, 0.0, 1.0];
        LandmarkFrame { t, pose: Some(pose), left_hand: None, right_hand: None, pose_image: None }
    }

    #[test]
    fn a_swinging_raised_hand_is_a_wave_and_a_held_point_is_not() {
        let wave: Vec<_> = (0..15).map(|i| frame(i as f32 / 10.0, 0.12 * (i as f32 * 1.3).sin(), -0.7)).collect();
        assert!(waving(&wave));
        let point: Vec<_> = (0..15).map(|i| frame(i as f32 / 10.0, -0.5, -0.5)).collect();
        assert!(!waving(&point));
        let low: Vec<_> = (0..15).map(|i| frame(i as f32 / 10.0, 0.12 * (i as f32 * 1.3).sin(), -0.2)).collect();
        assert!(!waving(&low));
    }

    /// A hand swung about once a second: read fast, the wave is read from the last second and a
    /// half; read slowly (a busy machine, two frames a second), from the last six frames, so the
    /// same swing is still a wave.
    #[test]
    fn a_wave_is_read_at_any_rate_from_a_second_and_a_half_or_six_frames() {
        let swing = |t: f32| frame(t, 0.12 * (t * 6.0).sin(), -0.7);
        let mut fast = Vec::new();
        for i in 0..60 {
            remember(&mut fast, swing(i as f32 / 20.0));
        }
        assert_eq!(fast.len(), 30, "1.5 s at 20 frames a second");
        assert!(waving(&fast));
        let mut slow = Vec::new();
        for i in 0..20 {
            remember(&mut slow, swing(i as f32 / 2.0));
        }
        assert_eq!(slow.len(), WAVE_FRAMES);
        assert!(waving(&slow));
        let mut still = Vec::new();
        for i in 0..20 {
            remember(&mut still, frame(i as f32 / 2.0, -0.5, -0.5));
        }
        assert!(!waving(&still));
    }

    #[test]
    fn frames_that_are_too_large_or_not_jpegs_are_refused() {
        let jpeg = [0xFF, 0xD8, 0xFF, 0xE0, 0, 0];
        assert_eq!(refusal(&jpeg), None);
        assert!(refusal(b"\x89PNG....").unwrap().contains("not a JPEG"));
        let mut big = vec![0u8; MAX_FRAME_BYTES + 1];
        big[..3].copy_from_slice(&[0xFF, 0xD8, 0xFF]);
        assert!(refusal(&big).unwrap().contains("at most"));
    }
}
