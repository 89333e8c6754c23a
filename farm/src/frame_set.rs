//! A set of labelled RGB-D frames for pretraining the visual encoder: `orchestrator encoder
//! pretrain` renders it (with the simulator), `learner pretrain-encoder` trains on it (without).
//! Types, reader and writer only; no rendering.
//!
//! File layout, little-endian:
//! ```text
//! magic "GTHFRAME" | version u32 = 2
//! width u32 | height u32 | grid u32 | classes u32 | count u32 | seed u64
//! held-out rooms: n u32, then n × floorplan u16
//! count × frame: room u16 (floorplan) | flags u8 (bit 0: the person is in the scene)
//!                | person facing f32 (degrees, NaN without a person: see `FrameRef`)
//!                | rgb u8 H×W×3 | depth u16 H×W (the wire's 0..10 m → 0..65535)
//!                | cell class u8 grid×grid | cell mean depth u16 grid×grid (same unit)
//! ```
//! Rows top first; cells row-major. Frames are records so a writer appends them in order; the
//! reader keeps each field in one array over all frames (what a trainer slices batches from).
//! The cell labels and the person's facing are for the semantic sensor's training and for the
//! probes; a label-free encoder reads only the pixels.

use std::path::Path;

/// First bytes of every frame-set file.
pub const MAGIC: [u8; 8] = *b"GTHFRAME";
/// The layout above; a reader refuses any other.
pub const VERSION: u32 = 2;
/// Frame flag: the person stands in the scene (in view or not).
pub const FLAG_PERSON: u8 = 1;

/// Cell classes of the encoder's frame sets: the 37 target categories by their index
/// (`shm_schema::TARGET_CATEGORIES`, the policy's target vocabulary), then the person, then
/// everything else (structure, furniture that is no target, nothing).
pub const CLASS_PERSON: u8 = shm_schema::TARGET_CATEGORIES as u8;
pub const CLASS_OTHER: u8 = CLASS_PERSON + 1;
pub const CLASSES: u32 = CLASS_OTHER as u32 + 1;

/// What every frame of a set shares.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FrameSetHeader {
    pub width: u32,
    pub height: u32,
    /// Cells per side: the labels are `grid × grid` per frame.
    pub grid: u32,
    /// Number of classes a cell label can take (`0..classes`).
    pub classes: u32,
    /// The seed the frames were drawn from.
    pub seed: u64,
    /// Floorplan numbers of the rooms whose frames are kept out of training (for the held-out
    /// accuracy).
    pub held_out: Vec<u16>,
}

impl FrameSetHeader {
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn cells(&self) -> usize {
        self.grid as usize * self.grid as usize
    }

    /// Bytes of one frame record.
    fn record_bytes(&self) -> usize {
        7 + self.pixels() * 5 + self.cells() * 3
    }

    fn check(&self) -> Result<(), (String, String)> {
        let bad = |f: &str, m: String| Err((f.to_string(), m));
        if self.width == 0 || self.height == 0 || self.width > 4096 || self.height > 4096 {
            return bad("width", format!("frame size {}×{} must be 1..=4096 pixels a side", self.width, self.height));
        }
        if self.grid == 0 || !self.width.is_multiple_of(self.grid) || !self.height.is_multiple_of(self.grid) {
            return bad(
                "grid",
                format!("{} cells must divide the frame size {}×{}", self.grid, self.width, self.height),
            );
        }
        if !(1..=256).contains(&self.classes) {
            return bad("classes", format!("{} classes must be 1..=256 (labels are u8)", self.classes));
        }
        Ok(())
    }
}

/// One frame as a writer hands it over.
#[derive(Clone, Copy, Debug)]
pub struct FrameRef<'a> {
    /// Floorplan number of the room.
    pub room: u16,
    pub flags: u8,
    /// Where the person faces, relative to the robot: their yaw minus the yaw of the line from
    /// them to the camera, degrees in −180..180 (0: facing the robot); NaN without a person.
    pub person_facing: f32,
    /// `H × W × 3`.
    pub rgb: &'a [u8],
    /// `H × W`, 0..10 m → 0..65535.
    pub depth: &'a [u16],
    /// `grid × grid` labels below `classes`.
    pub cell_class: &'a [u8],
    /// `grid × grid` mean depth per cell, unit as `depth`.
    pub cell_depth: &'a [u16],
}

/// A whole set in memory, each field one array over all frames in order.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameSet {
    pub header: FrameSetHeader,
    pub rooms: Vec<u16>,
    pub flags: Vec<u8>,
    pub person_facing: Vec<f32>,
    pub rgb: Vec<u8>,
    pub depth: Vec<u16>,
    pub cell_class: Vec<u8>,
    pub cell_depth: Vec<u16>,
}

/// A frame-set file that cannot be used: which file, which field, why.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {field}: {message}")]
pub struct FrameSetError {
    pub file: String,
    pub field: String,
    pub message: String,
}

impl FrameSet {
    /// An empty set; fails when the header cannot describe frames (sizes, grid, classes).
    pub fn new(header: FrameSetHeader) -> Result<FrameSet, FrameSetError> {
        header.check().map_err(|(field, message)| FrameSetError { file: "(new frame set)".into(), field, message })?;
        Ok(FrameSet {
            header,
            rooms: Vec::new(),
            flags: Vec::new(),
            person_facing: Vec::new(),
            rgb: Vec::new(),
            depth: Vec::new(),
            cell_class: Vec::new(),
            cell_depth: Vec::new(),
        })
    }

    pub fn len(&self) -> usize {
        self.rooms.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rooms.is_empty()
    }

    /// Appends a frame; its slices must have the header's sizes and its labels be below `classes`.
    pub fn push(&mut self, f: &FrameRef<'_>) -> Result<(), FrameSetError> {
        let h = &self.header;
        let i = self.len();
        let err = |field: &str, message: String| FrameSetError {
            file: "(new frame set)".into(),
            field: format!("frame {i} {field}"),
            message,
        };
        for (field, got, want) in [
            ("rgb", f.rgb.len(), h.pixels() * 3),
            ("depth", f.depth.len(), h.pixels()),
            ("cell class", f.cell_class.len(), h.cells()),
            ("cell depth", f.cell_depth.len(), h.cells()),
        ] {
            if got != want {
                return Err(err(field, format!("{got} values, expected {want}")));
            }
        }
        if let Some(c) = f.cell_class.iter().find(|&&c| u32::from(c) >= h.classes) {
            return Err(err("cell class", format!("label {c} is not below {} classes", h.classes)));
        }
        self.rooms.push(f.room);
        self.flags.push(f.flags);
        self.person_facing.push(f.person_facing);
        self.rgb.extend_from_slice(f.rgb);
        self.depth.extend_from_slice(f.depth);
        self.cell_class.extend_from_slice(f.cell_class);
        self.cell_depth.extend_from_slice(f.cell_depth);
        Ok(())
    }

    /// Frame `i` as slices into the arrays.
    pub fn frame(&self, i: usize) -> FrameRef<'_> {
        let (px, cells) = (self.header.pixels(), self.header.cells());
        FrameRef {
            room: self.rooms[i],
            flags: self.flags[i],
            person_facing: self.person_facing[i],
            rgb: &self.rgb[i * px * 3..(i + 1) * px * 3],
            depth: &self.depth[i * px..(i + 1) * px],
            cell_class: &self.cell_class[i * cells..(i + 1) * cells],
            cell_depth: &self.cell_depth[i * cells..(i + 1) * cells],
        }
    }

    /// Whether frame `i` comes from a held-out room.
    pub fn is_held_out(&self, i: usize) -> bool {
        self.header.held_out.contains(&self.rooms[i])
    }

    /// The file's bytes (layout in the module doc).
    pub fn to_bytes(&self) -> Vec<u8> {
        let h = &self.header;
        let mut out = Vec::with_capacity(48 + h.held_out.len() * 2 + self.len() * h.record_bytes());
        out.extend_from_slice(&MAGIC);
        for v in [VERSION, h.width, h.height, h.grid, h.classes, self.len() as u32] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&h.seed.to_le_bytes());
        out.extend_from_slice(&(h.held_out.len() as u32).to_le_bytes());
        for r in &h.held_out {
            out.extend_from_slice(&r.to_le_bytes());
        }
        for i in 0..self.len() {
            let f = self.frame(i);
            out.extend_from_slice(&f.room.to_le_bytes());
            out.push(f.flags);
            out.extend_from_slice(&f.person_facing.to_le_bytes());
            out.extend_from_slice(f.rgb);
            out.extend(f.depth.iter().flat_map(|v| v.to_le_bytes()));
            out.extend_from_slice(f.cell_class);
            out.extend(f.cell_depth.iter().flat_map(|v| v.to_le_bytes()));
        }
        out
    }

    /// Writes the file atomically (a reader never sees half a set).
    pub fn write(&self, path: &Path) -> Result<(), FrameSetError> {
        crate::files::write_atomic(path, &self.to_bytes()).map_err(|e| FrameSetError {
            file: path.display().to_string(),
            field: "(file)".into(),
            message: format!("cannot write: {e}"),
        })
    }

    pub fn read(path: &Path) -> Result<FrameSet, FrameSetError> {
        let bytes = std::fs::read(path).map_err(|e| FrameSetError {
            file: path.display().to_string(),
            field: "(file)".into(),
            message: format!("cannot read: {e}"),
        })?;
        FrameSet::from_bytes(&bytes, &path.display().to_string())
    }

    /// Parses a file's bytes; `file` names it in errors.
    pub fn from_bytes(bytes: &[u8], file: &str) -> Result<FrameSet, FrameSetError> {
        let mut r = Reader { bytes, at: 0, file };
        let magic = r.take("magic", 8)?;
        if magic != MAGIC {
            return Err(r.error("magic", "not a frame-set file (made by `orchestrator encoder pretrain`)".into()));
        }
        let version = r.u32("version")?;
        if version != VERSION {
            return Err(r.error("version", format!("version {version}; this build reads version {VERSION}")));
        }
        let (width, height, grid, classes) = (r.u32("width")?, r.u32("height")?, r.u32("grid")?, r.u32("classes")?);
        let count = r.u32("count")? as usize;
        let seed = r.u64("seed")?;
        let n_held = r.u32("held-out rooms")? as usize;
        let held_out =
            (0..n_held).map(|k| r.u16(&format!("held-out room {k}"))).collect::<Result<Vec<u16>, FrameSetError>>()?;
        let header = FrameSetHeader { width, height, grid, classes, seed, held_out };
        header.check().map_err(|(field, message)| r.error(&field, message))?;
        let need = count.checked_mul(header.record_bytes()).unwrap_or(usize::MAX);
        if bytes.len() - r.at != need {
            return Err(r.error(
                "count",
                format!(
                    "{count} frames of {} bytes need {need} bytes after the header, the file has {} (truncated?)",
                    header.record_bytes(),
                    bytes.len() - r.at
                ),
            ));
        }
        let (px, cells) = (header.pixels(), header.cells());
        let mut set = FrameSet::new(header).map_err(|e| r.error(&e.field, e.message))?;
        set.rgb.reserve_exact(count * px * 3);
        set.depth.reserve_exact(count * px);
        for i in 0..count {
            set.rooms.push(r.u16("room")?);
            set.flags.push(r.take("flags", 1)?[0]);
            set.person_facing.push(f32::from_le_bytes(r.take("person facing", 4)?.try_into().expect("4 bytes")));
            set.rgb.extend_from_slice(r.take("rgb", px * 3)?);
            set.depth.extend(r.take("depth", px * 2)?.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])));
            let labels = r.take("cell class", cells)?;
            if let Some(c) = labels.iter().find(|&&c| u32::from(c) >= classes) {
                return Err(
                    r.error(&format!("frame {i} cell class"), format!("label {c} is not below {classes} classes"))
                );
            }
            set.cell_class.extend_from_slice(labels);
            set.cell_depth
                .extend(r.take("cell depth", cells * 2)?.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])));
        }
        Ok(set)
    }
}

/// A cursor over a file's bytes that names the field it could not read.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    file: &'a str,
}

impl<'a> Reader<'a> {
    fn error(&self, field: &str, message: String) -> FrameSetError {
        FrameSetError { file: self.file.to_string(), field: field.to_string(), message }
    }

    fn take(&mut self, field: &str, n: usize) -> Result<&'a [u8], FrameSetError> {
        let end = self.at + n;
        if end > self.bytes.len() {
            return Err(self.error(
                field,
                format!(
                    "the file ends at byte {}, {n} more bytes expected at {} (truncated?)",
                    self.bytes.len(),
                    self.at
                ),
            ));
        }
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn u16(&mut self, field: &str) -> Result<u16, FrameSetError> {
        Ok(u16::from_le_bytes(self.take(field, 2)?.try_into().expect("2 bytes")))
    }

    fn u32(&mut self, field: &str) -> Result<u32, FrameSetError> {
        Ok(u32::from_le_bytes(self.take(field, 4)?.try_into().expect("4 bytes")))
    }

    fn u64(&mut self, field: &str) -> Result<u64, FrameSetError> {
        Ok(u64::from_le_bytes(self.take(field, 8)?.try_into().expect("8 bytes")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two 2×2 frames, one cell each, three classes.
    fn tiny() -> FrameSet {
        let header = FrameSetHeader { width: 2, height: 2, grid: 1, classes: 3, seed: 7, held_out: vec![430] };
        let mut s = FrameSet::new(header).unwrap();
        let rgb: Vec<u8> = (0..12).collect();
        s.push(&FrameRef {
            room: 1,
            flags: FLAG_PERSON,
            person_facing: -30.0,
            rgb: &rgb,
            depth: &[0, 1, 0x1234, 65535],
            cell_class: &[2],
            cell_depth: &[0x1000],
        })
        .unwrap();
        s.push(&FrameRef {
            room: 430,
            flags: 0,
            person_facing: f32::NAN,
            rgb: &[9; 12],
            depth: &[7; 4],
            cell_class: &[0],
            cell_depth: &[7],
        })
        .unwrap();
        s
    }

    /// The bytes of [`tiny`], written out by hand from the layout in the module doc.
    fn golden() -> Vec<u8> {
        let mut g = Vec::new();
        g.extend_from_slice(b"GTHFRAME");
        g.extend_from_slice(&[2, 0, 0, 0]); // version
        g.extend_from_slice(&[2, 0, 0, 0, 2, 0, 0, 0, 1, 0, 0, 0, 3, 0, 0, 0, 2, 0, 0, 0]); // w h grid classes count
        g.extend_from_slice(&[7, 0, 0, 0, 0, 0, 0, 0]); // seed
        g.extend_from_slice(&[1, 0, 0, 0, 0xAE, 0x01]); // one held-out room: 430
        g.extend_from_slice(&[1, 0, 1]); // room 1, person
        g.extend_from_slice(&[0, 0, 0xF0, 0xC1]); // facing -30.0
        g.extend(0..12u8);
        g.extend_from_slice(&[0, 0, 1, 0, 0x34, 0x12, 0xFF, 0xFF]);
        g.extend_from_slice(&[2, 0x00, 0x10]);
        g.extend_from_slice(&[0xAE, 0x01, 0]); // room 430, no person
        g.extend_from_slice(&f32::NAN.to_le_bytes());
        g.extend_from_slice(&[9; 12]);
        g.extend_from_slice(&[7, 0, 7, 0, 7, 0, 7, 0]);
        g.extend_from_slice(&[0, 7, 0]);
        g
    }

    #[test]
    fn golden_bytes_and_back() {
        let s = tiny();
        assert_eq!(s.to_bytes(), golden());
        let back = FrameSet::from_bytes(&golden(), "g.frames").unwrap();
        assert_eq!(back.to_bytes(), s.to_bytes(), "NaN facings make PartialEq useless here");
        assert_eq!(back.person_facing[0], -30.0);
        assert!(back.person_facing[1].is_nan());
        assert!(!back.is_held_out(0) && back.is_held_out(1));
        assert_eq!(back.frame(0).depth, &[0, 1, 0x1234, 65535]);
    }

    #[test]
    fn writes_and_reads_a_file() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.frames");
        tiny().write(&p).unwrap();
        assert_eq!(FrameSet::read(&p).unwrap().to_bytes(), tiny().to_bytes());
    }

    #[test]
    fn bad_input_names_the_file_and_field() {
        let msg = |bytes: &[u8]| FrameSet::from_bytes(bytes, "enc/x.frames").unwrap_err().to_string();
        let g = golden();
        let m = msg(&g[..g.len() - 1]);
        assert!(m.starts_with("enc/x.frames: count:") && m.contains("truncated"), "{m}");
        let m = msg(&g[..18]);
        assert!(m.starts_with("enc/x.frames: height:"), "{m}");
        let mut v = g.clone();
        v[0] = b'X';
        assert!(msg(&v).starts_with("enc/x.frames: magic:"));
        let mut v = g.clone();
        v[8] = 1;
        assert!(msg(&v).contains("version 1"));
        let mut v = g.clone();
        v[20] = 0; // grid 0
        assert!(msg(&v).starts_with("enc/x.frames: grid:"));
        let mut v = g.clone();
        v[46 + 3 + 4 + 12 + 8] = 3; // first frame's cell label = classes
        let m = msg(&v);
        assert!(m.contains("frame 0 cell class") && m.contains("label 3"), "{m}");
        let e = FrameSet::read(Path::new("/nonexistent/y.frames")).unwrap_err().to_string();
        assert!(e.contains("/nonexistent/y.frames") && e.contains("cannot read"), "{e}");
    }

    #[test]
    fn push_checks_sizes_and_labels() {
        let (mut s, other) = (tiny(), tiny());
        let e = s.push(&FrameRef { rgb: &[0; 11], ..other.frame(1) }).unwrap_err();
        assert!(e.to_string().contains("frame 2 rgb"), "{e}");
        let e = s.push(&FrameRef { cell_class: &[5], ..other.frame(1) }).unwrap_err();
        assert!(e.to_string().contains("label 5"), "{e}");
        assert_eq!(s.len(), 2);
    }
}
