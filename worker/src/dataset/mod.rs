//! The GOND dataset on disk: a folder that many worker processes open at once without copying.
//!
//! ```text
//! DIR/manifest.json          what is here: splits, counts, checksums, build parameters
//! DIR/scenes/FloorPlanN.json the 120 rooms (serde, hand-editable)
//! DIR/<split>.json           the program index (serde, one object per program)
//! DIR/<split>.gond           binary: header, motions (f16, 19,000 B each), program records (80 B each)
//! DIR/interventions.gond     the 20 intervention motions, same format (records zeroed)
//! ```
//! The `.gond` files are memory-mapped; a worker reads a program's record and motion in place.
//! Motions are stored as IEEE f16: 19,000 bytes per program, exact enough for muscle values
//! in [−1, 1] (error ≤ 2.5e-4) and independent of the synthesiser's code version (regenerating
//! from seeds would tie old datasets to new code).
//!
//! Opening checks everything that can be checked cheaply (sizes, magic, version, counts,
//! record sanity); `Verify::Full` also re-hashes every byte against the manifest. A bad
//! dataset is one error naming the file and what is wrong, never a panic later.

pub mod build;
pub mod starts;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use half::f16;
use memmap2::Mmap;
use serde::{Deserialize, Serialize};

use crate::program::{Program, ProgramRecord};
use crate::scene::{Scene, SceneId, Split};

pub const FORMAT: &str = "gesthor-gond";
/// 2: records carry the start's geodesic distance to the target's centre and whether it is
/// already successful (in what was padding), and the manifest how starts were drawn.
pub const VERSION: u32 = 2;
pub const FRAMES: usize = 100;
pub const DIMS: usize = 95;
/// Values in one motion.
pub const MOTION_LEN: usize = FRAMES * DIMS;
const MOTION_BYTES: usize = MOTION_LEN * 2;
const RECORD_BYTES: usize = std::mem::size_of::<ProgramRecord>();
const MAGIC: [u8; 8] = *b"GONDBIN1";
const HEADER_BYTES: usize = 64;

/// One split's entry in the manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SplitEntry {
    pub programs: u64,
    pub index: String,
    pub data: String,
    /// xxh3-64 of the whole `.gond` file, hex.
    pub checksum: String,
    /// Share of programs whose room holds more than one instance of the target category.
    pub multi_instance_share: f64,
}

/// Parameters the dataset was built with (kept so that a build can be reproduced).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BuildParams {
    pub seed: u64,
    pub train_programs: u64,
    pub val_per_room: u64,
    pub test_per_room: u64,
    pub success_distance: f32,
    pub robot_radius: f32,
    pub fov_deg: f32,
    /// Person stands this far from the target (metres, 2D).
    pub human_distance: [f32; 2],
    /// How robot starts were drawn (`dataset::starts`; manifests before this field: far).
    #[serde(default = "starts::Starts::before_option")]
    pub starts: starts::Starts,
    /// `dissertation` starts: the mean geodesic distance start → target's centre asked for.
    #[serde(default)]
    pub start_mean_geodesic: f32,
    /// `dissertation` starts: the power of the distance in their weight (`starts::tilt`).
    #[serde(default)]
    pub start_shape: f32,
    /// `far` starts: this far (geodesic) from the success region.
    pub start_geodesic: [f32; 2],
    /// How cleanly the people point (datasets from before this field: clean).
    #[serde(default)]
    pub pointing: crate::gesture::Pointing,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    pub frames: u32,
    pub dims: u32,
    pub motion_dtype: String,
    pub build: BuildParams,
    pub scenes: String,
    pub splits: BTreeMap<String, SplitEntry>,
    pub interventions: SplitEntry,
    pub intervention_names: Vec<String>,
}

/// What is wrong with a dataset folder.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: no dataset here (no manifest.json); build one with `orchestrator dataset build --out {dir}`")]
    Missing { path: String, dir: String },
    #[error("{path}: {message}")]
    Bad { path: String, message: String },
    #[error("{path}: field `{field}`: {message}")]
    Field { path: String, field: String, message: String },
    #[error("{path}: {reason}")]
    Io { path: String, reason: std::io::Error },
}

fn bad(path: &Path, message: impl Into<String>) -> DatasetError {
    DatasetError::Bad { path: path.display().to_string(), message: message.into() }
}

/// How much to check when opening.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verify {
    /// Sizes, headers, counts, record sanity: cheap, done by every worker.
    Quick,
    /// Also the checksum of every byte and the JSON index against the binary records.
    Full,
}

/// A memory-mapped `.gond` file.
pub struct GondFile {
    path: PathBuf,
    map: Mmap,
    count: usize,
}

impl GondFile {
    fn open(path: &Path, expect_count: u64) -> Result<GondFile, DatasetError> {
        let f = std::fs::File::open(path)
            .map_err(|reason| DatasetError::Io { path: path.display().to_string(), reason })?;
        // SAFETY: dataset files are written once (atomically renamed into place) and never
        // modified in place; readers only ever map complete files.
        let map =
            unsafe { Mmap::map(&f) }.map_err(|reason| DatasetError::Io { path: path.display().to_string(), reason })?;
        if map.len() < HEADER_BYTES {
            return Err(bad(
                path,
                format!("truncated: {} bytes, shorter than the {HEADER_BYTES}-byte header", map.len()),
            ));
        }
        if map[..8] != MAGIC {
            return Err(bad(path, "not a GOND binary file (bad magic)"));
        }
        let word = |o: usize| u32::from_le_bytes(map[o..o + 4].try_into().unwrap());
        let version = word(8);
        if version != VERSION {
            return Err(bad(path, format!("format version {version}, this build reads {VERSION}")));
        }
        let count = u64::from_le_bytes(map[12..20].try_into().unwrap());
        let (frames, dims) = (word(20) as usize, word(24) as usize);
        if frames != FRAMES || dims != DIMS {
            return Err(bad(path, format!("motions are {frames}×{dims}, expected {FRAMES}×{DIMS}")));
        }
        if count != expect_count {
            return Err(bad(path, format!("holds {count} programs, the manifest says {expect_count}")));
        }
        let want = HEADER_BYTES as u64 + count * (RECORD_BYTES + MOTION_BYTES) as u64;
        if map.len() as u64 != want {
            return Err(bad(
                path,
                format!("truncated or padded: {} bytes, expected {want} for {count} programs", map.len()),
            ));
        }
        Ok(GondFile { path: path.to_path_buf(), map, count: count as usize })
    }

    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    pub fn record(&self, i: usize) -> ProgramRecord {
        let o = HEADER_BYTES + self.count * MOTION_BYTES + i * RECORD_BYTES;
        bytemuck::pod_read_unaligned(&self.map[o..o + RECORD_BYTES])
    }

    /// The motion of program `i` as f16 values (frame-major, 100 × 95), in place.
    pub fn motion_f16(&self, i: usize) -> &[f16] {
        let o = HEADER_BYTES + i * MOTION_BYTES;
        bytemuck::cast_slice(&self.map[o..o + MOTION_BYTES])
    }

    /// The motion of program `i` as f32.
    pub fn motion(&self, i: usize) -> Vec<f32> {
        self.motion_f16(i).iter().map(|v| v.to_f32()).collect()
    }

    fn checksum(&self) -> String {
        format!("{:016x}", xxhash_rust::xxh3::xxh3_64(&self.map))
    }
}

/// Streams a `.gond` file: the header, each motion as it comes, the records at the end; the
/// file appears under its name only when complete (temporary name + rename).
pub struct GondWriter {
    path: PathBuf,
    tmp: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
    hasher: xxhash_rust::xxh3::Xxh3,
    count: usize,
    records: Vec<ProgramRecord>,
    buf: Vec<u8>,
}

impl GondWriter {
    pub fn create(path: &Path, count: usize) -> std::io::Result<GondWriter> {
        let tmp = path.with_extension("gond.partial");
        if let Some(d) = path.parent() {
            std::fs::create_dir_all(d)?;
        }
        let out = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(&tmp)?);
        let mut w = GondWriter {
            path: path.to_path_buf(),
            tmp,
            out,
            hasher: xxhash_rust::xxh3::Xxh3::new(),
            count,
            records: Vec::with_capacity(count),
            buf: Vec::with_capacity(MOTION_BYTES),
        };
        let mut header = Vec::with_capacity(HEADER_BYTES);
        header.extend_from_slice(&MAGIC);
        header.extend_from_slice(&VERSION.to_le_bytes());
        header.extend_from_slice(&(count as u64).to_le_bytes());
        header.extend_from_slice(&(FRAMES as u32).to_le_bytes());
        header.extend_from_slice(&(DIMS as u32).to_le_bytes());
        header.resize(HEADER_BYTES, 0);
        w.write(&header)?;
        Ok(w)
    }

    fn write(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        use std::io::Write;
        self.hasher.update(bytes);
        self.out.write_all(bytes)
    }

    /// Appends one program (its motion: 100 × 95 values, frame-major).
    pub fn push(&mut self, record: ProgramRecord, motion: &[f32]) -> std::io::Result<()> {
        assert_eq!(motion.len(), MOTION_LEN, "a motion is {FRAMES}×{DIMS}");
        assert!(self.records.len() < self.count, "more programs than announced");
        let mut buf = std::mem::take(&mut self.buf);
        buf.clear();
        for v in motion {
            buf.extend_from_slice(&f16::from_f32(*v).to_le_bytes());
        }
        self.write(&buf)?;
        self.buf = buf;
        self.records.push(record);
        Ok(())
    }

    /// Writes the records, syncs and renames into place; returns the checksum.
    pub fn finish(mut self) -> std::io::Result<String> {
        use std::io::Write;
        assert_eq!(self.records.len(), self.count, "fewer programs than announced");
        let records = std::mem::take(&mut self.records);
        self.write(bytemuck::cast_slice(&records))?;
        self.out.flush()?;
        self.out.get_ref().sync_all()?;
        std::fs::rename(&self.tmp, &self.path)?;
        Ok(format!("{:016x}", self.hasher.digest()))
    }
}

/// Writes a whole `.gond` file at once (small files: interventions, tests).
pub fn write_gond(path: &Path, records: &[ProgramRecord], motions: &[Vec<f32>]) -> std::io::Result<String> {
    assert_eq!(records.len(), motions.len());
    let mut w = GondWriter::create(path, records.len())?;
    for (r, m) in records.iter().zip(motions) {
        w.push(*r, m)?;
    }
    w.finish()
}

/// Writes into `dir` a dataset of `programs` of one split with their own motions, reading its
/// rooms and intervention gestures from `base` (named by absolute path, not copied): a person's
/// own gesture in place of a program's, run by the same farm and evaluation as any dataset.
pub fn write_subset(dir: &Path, base: &Dataset, split: Split, programs: &[(Program, Vec<f32>)]) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let base_dir = std::path::absolute(&base.dir)?;
    let index: Vec<Program> =
        programs.iter().enumerate().map(|(i, (p, _))| Program { id: i as u64, ..p.clone() }).collect();
    let records: Vec<ProgramRecord> = index.iter().map(Program::to_record).collect();
    let motions: Vec<Vec<f32>> = programs.iter().map(|(_, m)| m.clone()).collect();
    let data = format!("{}.gond", split.name());
    let checksum = write_gond(&dir.join(&data), &records, &motions)?;
    let idx = format!("{}.json", split.name());
    farm::files::write_atomic(&dir.join(&idx), (serde_json::to_string_pretty(&index)? + "\n").as_bytes())?;
    let multi = index.iter().filter(|p| p.instances > 1).count() as f64 / index.len().max(1) as f64;
    let mut m = base.manifest.clone();
    m.scenes = base_dir.join(&m.scenes).display().to_string();
    m.interventions.data = base_dir.join(&m.interventions.data).display().to_string();
    m.splits = BTreeMap::from([(
        split.name().to_string(),
        SplitEntry { programs: index.len() as u64, index: idx, data, checksum, multi_instance_share: multi },
    )]);
    farm::files::write_atomic(&dir.join("manifest.json"), (serde_json::to_string_pretty(&m)? + "\n").as_bytes())
}

/// An open dataset.
pub struct Dataset {
    pub dir: PathBuf,
    pub manifest: Manifest,
    splits: BTreeMap<Split, GondFile>,
    interventions: GondFile,
}

impl Dataset {
    pub fn open(dir: &Path, verify: Verify) -> Result<Dataset, DatasetError> {
        let mpath = dir.join("manifest.json");
        if !mpath.exists() {
            return Err(DatasetError::Missing { path: mpath.display().to_string(), dir: dir.display().to_string() });
        }
        let text = std::fs::read_to_string(&mpath)
            .map_err(|reason| DatasetError::Io { path: mpath.display().to_string(), reason })?;
        let de = &mut serde_json::Deserializer::from_str(&text);
        let manifest: Manifest = serde_path_to_error::deserialize(de).map_err(|e| DatasetError::Field {
            path: mpath.display().to_string(),
            field: e.path().to_string(),
            message: e.inner().to_string(),
        })?;
        if manifest.format != FORMAT || manifest.version != VERSION {
            return Err(bad(
                &mpath,
                format!(
                    "format {} v{}, this build reads {FORMAT} v{VERSION}; build it again with `orchestrator dataset build --out {} --force`",
                    manifest.format,
                    manifest.version,
                    dir.display()
                ),
            ));
        }
        let mut splits = BTreeMap::new();
        for (name, e) in &manifest.splits {
            let split = Split::from_name(name).ok_or_else(|| DatasetError::Field {
                path: mpath.display().to_string(),
                field: format!("splits.{name}"),
                message: "not a split (train, val, test)".into(),
            })?;
            let f = GondFile::open(&dir.join(&e.data), e.programs)?;
            check_records(&f)?;
            if verify == Verify::Full {
                verify_file(&f, &e.checksum)?;
                verify_index(&f, &dir.join(&e.index))?;
            }
            splits.insert(split, f);
        }
        let interventions = GondFile::open(&dir.join(&manifest.interventions.data), manifest.interventions.programs)?;
        if verify == Verify::Full {
            verify_file(&interventions, &manifest.interventions.checksum)?;
        }
        Ok(Dataset { dir: dir.to_path_buf(), manifest, splits, interventions })
    }

    pub fn split(&self, s: Split) -> Option<&GondFile> {
        self.splits.get(&s)
    }

    /// The split, or an error naming the dataset and the split.
    pub fn require(&self, s: Split) -> Result<&GondFile, DatasetError> {
        self.splits.get(&s).ok_or_else(|| bad(&self.dir.join("manifest.json"), format!("has no `{}` split", s.name())))
    }

    pub fn program(&self, s: Split, i: usize) -> Option<Program> {
        let f = self.splits.get(&s)?;
        (i < f.len()).then(|| Program::from_record(i as u64, &f.record(i))).flatten()
    }

    pub fn interventions(&self) -> &GondFile {
        &self.interventions
    }

    pub fn scene_path(&self, id: SceneId) -> PathBuf {
        self.dir.join(&self.manifest.scenes).join(format!("{}.json", id.name()))
    }

    pub fn scene(&self, id: SceneId) -> Result<Scene, crate::scene::SceneError> {
        Scene::load(&self.scene_path(id))
    }

    /// Reads the JSON index of a split.
    pub fn index(&self, s: Split) -> Result<Vec<Program>, DatasetError> {
        let e = self.manifest.splits.get(s.name()).ok_or_else(|| bad(&self.dir, format!("no `{}` split", s.name())))?;
        read_index(&self.dir.join(&e.index))
    }
}

fn check_records(f: &GondFile) -> Result<(), DatasetError> {
    for i in 0..f.len() {
        let r = f.record(i);
        if Program::from_record(i as u64, &r).is_none() {
            return Err(bad(
                &f.path,
                format!("program {i}: invalid room FloorPlan{} or category {}", r.floorplan, r.target),
            ));
        }
        let finite = r.target_pos.iter().chain(&r.human_pos).chain(&r.robot_pos).all(|v| v.is_finite());
        if !finite || !r.geodesic.is_finite() {
            return Err(bad(&f.path, format!("program {i}: non-finite position or distance (corrupted?)")));
        }
    }
    Ok(())
}

fn verify_file(f: &GondFile, want: &str) -> Result<(), DatasetError> {
    let got = f.checksum();
    if got != want {
        return Err(bad(
            &f.path,
            format!("checksum {got} does not match the manifest's {want}: the file is corrupted"),
        ));
    }
    Ok(())
}

fn read_index(path: &Path) -> Result<Vec<Program>, DatasetError> {
    let text = std::fs::read_to_string(path)
        .map_err(|reason| DatasetError::Io { path: path.display().to_string(), reason })?;
    let de = &mut serde_json::Deserializer::from_str(&text);
    serde_path_to_error::deserialize(de).map_err(|e| DatasetError::Field {
        path: path.display().to_string(),
        field: e.path().to_string(),
        message: e.inner().to_string(),
    })
}

fn verify_index(f: &GondFile, path: &Path) -> Result<(), DatasetError> {
    let index = read_index(path)?;
    if index.len() != f.len() {
        return Err(bad(path, format!("lists {} programs, the binary holds {}", index.len(), f.len())));
    }
    for (i, p) in index.iter().enumerate() {
        if p.id != i as u64 || p.to_record() != f.record(i) {
            return Err(bad(path, format!("program {i} differs from its binary record in {}", f.path.display())));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f16_motions_round_trip_within_tolerance() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.gond");
        let rec = ProgramRecord { floorplan: 1, ..bytemuck::Zeroable::zeroed() };
        let m: Vec<f32> = (0..MOTION_LEN).map(|i| ((i as f32) * 0.37).sin()).collect();
        write_gond(&p, &[rec], &[m.clone()]).unwrap();
        let f = GondFile::open(&p, 1).unwrap();
        let back = f.motion(0);
        let err = m.iter().zip(&back).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(err <= 2.5e-4, "max error {err}");
        assert_eq!(f.record(0), rec);
    }

    #[test]
    fn truncated_file_is_one_clear_error() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.gond");
        let rec = ProgramRecord { floorplan: 1, ..bytemuck::Zeroable::zeroed() };
        write_gond(&p, &[rec, rec], &[vec![0.0; MOTION_LEN], vec![0.0; MOTION_LEN]]).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 100]).unwrap();
        let err = GondFile::open(&p, 2).err().unwrap().to_string();
        assert!(err.contains("x.gond") && err.contains("truncated"), "{err}");
        std::fs::write(&p, b"hello").unwrap();
        let err = GondFile::open(&p, 2).err().unwrap().to_string();
        assert!(err.contains("truncated"), "{err}");
    }
}
