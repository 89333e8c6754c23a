//! The person's own gesture, from any of the page's sources: captured from the webcam, read
//! from an uploaded video (the landmark model over its frames, as `gesture capture` reads one),
//! or an uploaded motion file (the 95 muscles, as `gesture capture` writes and `follow` reads).
//! Landmarks are fitted to each program's person at its start; a motion file is performed as
//! recorded.

use std::path::{Path, PathBuf};

use anyhow::Context;

use worker::gesture::Motion;
use worker::gesture::capture::{Capture, CaptureOptions, LandmarkFrame, capture};
use worker::gesture::motion::read_csv;
use worker::humanoid::{Humanoid, Side, Skeleton};

use super::wire::ToPage;

/// An uploaded file larger than this is refused (a 10 s phone video at 720p is ≈ 20 MiB).
pub const MAX_UPLOAD_BYTES: usize = 64 * 1024 * 1024;

/// A person's gesture, as it came.
#[derive(Clone, Debug)]
pub enum PersonGesture {
    /// A video's or the webcam's landmarks, fitted to a program's person when it starts.
    Landmarks(Vec<LandmarkFrame>),
    /// The 95 muscles, as recorded.
    Motion(Motion),
}

impl PersonGesture {
    /// The gesture as `skeleton` performs it.
    pub fn motion(&self, skeleton: &Skeleton) -> anyhow::Result<Motion> {
        match self {
            PersonGesture::Landmarks(frames) => Ok(muscles(skeleton, frames)?.motion),
            PersonGesture::Motion(m) => Ok(m.clone()),
        }
    }
}

/// A person's gesture in the 95 muscles of `skeleton`, from a capture's frames (as `gesture
/// capture` reads a video; a hand the small webcam frames lose is kept relaxed).
pub fn muscles(skeleton: &Skeleton, frames: &[LandmarkFrame]) -> anyhow::Result<Capture> {
    capture(skeleton, frames, CaptureOptions { hands_optional: true }).map_err(|e| anyhow::anyhow!("{e}"))
}

pub fn arm_name(side: Side) -> &'static str {
    if side == Side::Left { "left" } else { "right" }
}

/// A file name as uploaded, kept only if it is a plain name: letters, digits, `.`, `-`, `_`.
pub fn upload_name(name: &str) -> anyhow::Result<&str> {
    let plain = !name.is_empty()
        && name.len() <= 100
        && !name.starts_with('.')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_'));
    anyhow::ensure!(plain, "an upload named `{name}`: a file name of letters, digits, `.`, `-` and `_`, please");
    Ok(name)
}

/// Keeps an uploaded file in `dir` (never over another: `NAME`, then `2-NAME`, …) and reads it
/// into a gesture: a `.csv` is a motion file, anything else a video. Returns the gesture and
/// what the page is told of it.
pub fn read_upload(dir: &Path, name: &str, bytes: &[u8]) -> anyhow::Result<(PersonGesture, ToPage)> {
    let name = upload_name(name)?;
    anyhow::ensure!(!bytes.is_empty(), "{name}: the file is empty");
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = free_path(dir, name);
    std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))?;
    if name.to_ascii_lowercase().ends_with(".csv") {
        let m = read_csv(&path).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        let told =
            ToPage::Uploaded { name: name.into(), kind: "motion".into(), arm: None, frames: 100, person_frames: 0 };
        return Ok((PersonGesture::Motion(m), told));
    }
    let source = path.display().to_string();
    let frames = crate::commands::gesture::landmarks(&source, &path.with_extension("landmarks.jsonl"), None, 60.0)
        .with_context(|| format!("{name}: reading it as a video"))?;
    // fitted to a default person here to say what was found; to each program's at its start
    let c = muscles(Humanoid::seeded(0).skeleton(), &frames).with_context(|| format!("{name}: no gesture found"))?;
    let told = ToPage::Uploaded {
        name: name.into(),
        kind: "video".into(),
        arm: Some(arm_name(c.side).into()),
        frames: c.frames.len(),
        person_frames: c.person_frames,
    };
    Ok((PersonGesture::Landmarks(frames), told))
}

fn free_path(dir: &Path, name: &str) -> PathBuf {
    let mut path = dir.join(name);
    let mut n = 2;
    while path.exists() {
        path = dir.join(format!("{n}-{name}"));
        n += 1;
    }
    path
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upload_names_are_plain_file_names() {
        assert_eq!(upload_name("me_pointing-2.mp4").unwrap(), "me_pointing-2.mp4");
        for bad in ["", "../x.csv", "a/b.csv", ".hidden", "x y.mp4", "é.mp4"] {
            assert!(upload_name(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn an_upload_never_replaces_an_earlier_one_and_a_bad_motion_file_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_upload(dir.path(), "mine.csv", b"not,a\nmotion\n").unwrap_err();
        assert!(format!("{e:#}").contains("mine.csv"), "{e:#}");
        assert!(read_upload(dir.path(), "mine.csv", b"still not").is_err());
        let kept: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(kept.len(), 2, "{kept:?}");
        assert!(read_upload(dir.path(), "empty.csv", b"").unwrap_err().to_string().contains("empty"));
    }

    #[test]
    fn an_uploaded_motion_file_is_performed_as_recorded() {
        let dir = tempfile::tempdir().unwrap();
        let wave = worker::gesture::intervention(1);
        let file = dir.path().join("wave.csv");
        worker::gesture::motion::write_csv(&file, &wave).unwrap();
        let (g, told) = read_upload(&dir.path().join("uploads"), "wave.csv", &std::fs::read(&file).unwrap()).unwrap();
        assert!(matches!(told, ToPage::Uploaded { ref kind, .. } if kind == "motion"), "{told:?}");
        let m = g.motion(Humanoid::seeded(3).skeleton()).unwrap();
        let worst = m.as_flat().iter().zip(wave.as_flat()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        // to the CSV's three decimals
        assert!(worst <= 5.01e-4, "{worst}");
    }
}
