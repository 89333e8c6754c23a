//! The original recorder's file formats, read and written byte for byte as it did.
//!
//! **motion.csv** — a header of muscle indices `0;1;…;94`, then 100 rows of 95 values, `;`
//! separated, CRLF line ends, values rounded to 3 decimals and written in their shortest form
//! (`0`, `-1`, `0.6`, `-0.056`). Reading also accepts LF line ends, a missing final line end,
//! a header of muscle names instead of indices, a trailing `;` on a row and a decimal comma.
//!
//! **metadata JSON** (T3.1) — Unity's `JsonUtility` output of the recorder's `GestureRecording`:
//! 4-space indentation, no final newline, positions divided by 10 and the person's yaw divided
//! by 360. [`Metadata`] keeps that form; its methods convert to metres and degrees.

use std::path::Path;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize, Serializer};

use super::{FRAMES, Motion};
use crate::humanoid::{MUSCLE_NAMES, MUSCLES};

/// A gesture file that cannot be used, naming the file and the place in it.
#[derive(Debug, thiserror::Error)]
pub enum MotionFileError {
    // Not a `source`: the reason is in the message once (a chain would print it twice).
    #[error("{file}: cannot read: {reason}")]
    Io { file: String, reason: std::io::Error },
    #[error("{file}: line {line}: {message}")]
    Line { file: String, line: usize, message: String },
    #[error("{file}: line {line}, column {column} ({muscle}): {message}")]
    Value { file: String, line: usize, column: usize, muscle: &'static str, message: String },
    #[error("{file}: field `{field}`: {message}")]
    Field { file: String, field: String, message: String },
}

/// Reads a motion.csv.
pub fn read_csv(path: &Path) -> Result<Motion, MotionFileError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|reason| MotionFileError::Io { file: file.clone(), reason })?;
    parse_csv_bytes(&bytes, &file)
}

/// Parses motion.csv bytes; `file` names the source in errors.
pub fn parse_csv_bytes(bytes: &[u8], file: &str) -> Result<Motion, MotionFileError> {
    let text = std::str::from_utf8(bytes).map_err(|e| MotionFileError::Line {
        file: file.to_string(),
        line: 1 + bytes[..e.valid_up_to()].iter().filter(|&&b| b == b'\n').count(),
        message: "not UTF-8 text".into(),
    })?;
    parse_csv(text, file)
}

/// Parses motion.csv text; `file` names the source in errors.
pub fn parse_csv(text: &str, file: &str) -> Result<Motion, MotionFileError> {
    let line_err = |line: usize, message: String| MotionFileError::Line { file: file.to_string(), line, message };
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text.split('\n').map(|l| l.strip_suffix('\r').unwrap_or(l)).enumerate().map(|(i, l)| (i + 1, l));

    let (_, header) = lines.next().unwrap_or((1, ""));
    let cols = fields(header);
    let by_index = cols.len() == MUSCLES && cols.iter().enumerate().all(|(i, c)| c.trim().parse::<usize>() == Ok(i));
    let by_name = cols.len() == MUSCLES && cols.iter().zip(MUSCLE_NAMES).all(|(c, n)| c.trim() == n);
    if !(by_index || by_name) {
        let shown: String = header.chars().take(40).collect();
        return Err(line_err(1, format!("expected the header `0;1;…;94` (or the 95 muscle names), found `{shown}`")));
    }

    let mut motion = Motion::constant(&[0.0; MUSCLES]);
    let mut rows = 0;
    let mut blank_from: Option<usize> = None;
    for (line, row) in lines {
        if row.trim().is_empty() {
            blank_from.get_or_insert(line);
            continue;
        }
        if let Some(b) = blank_from {
            return Err(line_err(b, "empty line inside the data".into()));
        }
        if rows == FRAMES {
            return Err(line_err(line, format!("more than {FRAMES} frames")));
        }
        let vals = fields(row);
        if vals.len() != MUSCLES {
            return Err(line_err(line, format!("expected {MUSCLES} values separated by `;`, found {}", vals.len())));
        }
        let frame = motion.frame_mut(rows);
        for (col, v) in vals.iter().enumerate() {
            frame[col] = parse_value(v).ok_or_else(|| MotionFileError::Value {
                file: file.to_string(),
                line,
                column: col + 1,
                muscle: MUSCLE_NAMES[col],
                message: format!("`{}` is not a finite number", v.trim()),
            })?;
        }
        rows += 1;
    }
    if rows < FRAMES {
        let end = 2 + rows;
        return Err(line_err(end, format!("expected {FRAMES} frames, the file ends after {rows}")));
    }
    Ok(motion)
}

/// The `;`-separated fields of a row; one empty field after a trailing `;` is dropped.
fn fields(row: &str) -> Vec<&str> {
    let mut v: Vec<&str> = row.split(';').collect();
    if v.len() == MUSCLES + 1 && v[MUSCLES].trim().is_empty() {
        v.pop();
    }
    v
}

fn parse_value(s: &str) -> Option<f32> {
    let s = s.trim();
    let v: f32 =
        if s.contains(',') && !s.contains('.') { s.replacen(',', ".", 1).parse().ok()? } else { s.parse().ok()? };
    v.is_finite().then_some(v)
}

/// A value as the recorder wrote it: rounded to 3 decimals, shortest form, no `-0`.
pub fn format_value(v: f32) -> String {
    let mut s = format!("{v:.3}");
    if s.contains('.') {
        let t = s.trim_end_matches('0').trim_end_matches('.').len();
        s.truncate(t);
    }
    if s == "-0" { "0".to_string() } else { s }
}

/// The first line of a motion.csv.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum CsvHeader {
    /// `0;1;…;94`, as the original recorder wrote it.
    #[default]
    Indices,
    /// The 95 muscle names (`Spine Front-Back;…`), for people reading the file.
    Names,
}

/// motion.csv text in the original form (index header, `;`, CRLF, 3-decimal values).
pub fn to_csv(m: &Motion) -> String {
    to_csv_with(m, CsvHeader::Indices)
}

/// motion.csv text with the chosen header; the rows are always in the original form.
pub fn to_csv_with(m: &Motion, header: CsvHeader) -> String {
    let mut out = String::with_capacity(60 * 1024);
    match header {
        CsvHeader::Indices => out.push_str(&(0..MUSCLES).map(|i| i.to_string()).collect::<Vec<_>>().join(";")),
        CsvHeader::Names => out.push_str(&MUSCLE_NAMES.join(";")),
    }
    out.push_str("\r\n");
    for frame in m.frames() {
        for (i, v) in frame.iter().enumerate() {
            if i > 0 {
                out.push(';');
            }
            out.push_str(&format_value(*v));
        }
        out.push_str("\r\n");
    }
    out
}

/// Writes a motion.csv in the original form atomically. A motion holding NaN or infinity is
/// refused.
pub fn write_csv(path: &Path, m: &Motion) -> std::io::Result<()> {
    write_csv_with(path, m, CsvHeader::Indices)
}

/// [`write_csv`] with the chosen header.
pub fn write_csv_with(path: &Path, m: &Motion, header: CsvHeader) -> std::io::Result<()> {
    if let Some(i) = m.as_flat().iter().position(|v| !v.is_finite()) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("frame {}, muscle {}: value {} is not finite", i / MUSCLES, i % MUSCLES, m.as_flat()[i]),
        ));
    }
    farm::files::write_atomic(path, to_csv_with(m, header).as_bytes())
}

/// A Unity `Vector3` as `JsonUtility` writes it (`{"x": …, "y": …, "z": …}`).
#[derive(Clone, Copy, Debug, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Xyz {
    pub x: f32,
    pub y: f32,
    pub z: f32,
}

impl Serialize for Xyz {
    /// Single-precision values widened to double, as `JsonUtility` prints them.
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut st = s.serialize_struct("Xyz", 3)?;
        st.serialize_field("x", &(self.x as f64))?;
        st.serialize_field("y", &(self.y as f64))?;
        st.serialize_field("z", &(self.z as f64))?;
        st.end()
    }
}

impl Xyz {
    fn from_vec(v: Vector3<f32>) -> Xyz {
        Xyz { x: v.x, y: v.y, z: v.z }
    }

    fn vec(&self) -> Vector3<f32> {
        Vector3::new(self.x, self.y, self.z)
    }
}

fn f32_as_f64<S: Serializer>(v: &f32, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_f64(*v as f64)
}

/// A recorded program's metadata (T3.1) in the original recorder's field names and scaling:
/// positions are metres ÷ 10 and `human_rot` is degrees ÷ 360. `target_to_human` is, despite
/// its name, the target minus the person's position.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Metadata {
    pub instruction: String,
    pub scene_type: String,
    pub scene_num: i64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene_name: Option<String>,
    pub target_type: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_sim_obj_type: Option<String>,
    #[serde(default, rename = "targetID", skip_serializing_if = "Option::is_none")]
    pub target_id: Option<String>,
    pub human_pos: Xyz,
    #[serde(serialize_with = "f32_as_f64")]
    pub human_rot: f32,
    pub target_pos: Xyz,
    pub target_to_human: Xyz,
    pub image: String,
    pub motion: String,
    pub audio: String,
}

/// The recorder's scale for positions (stored ÷ 10).
pub const POSITION_SCALE: f32 = 10.0;
/// The recorder's scale for the yaw (stored ÷ 360).
pub const YAW_SCALE: f32 = 360.0;

impl Metadata {
    /// Metadata for a program given in world units (metres, degrees); stores the original scaling.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        instruction: &str,
        scene_type: &str,
        scene_num: i64,
        target_type: &str,
        human_pos: Point3<f32>,
        human_yaw_deg: f32,
        target_pos: Point3<f32>,
        files: [&str; 3],
    ) -> Metadata {
        Metadata {
            instruction: instruction.into(),
            scene_type: scene_type.into(),
            scene_num,
            scene_name: None,
            target_type: target_type.into(),
            target_sim_obj_type: None,
            target_id: None,
            human_pos: Xyz::from_vec(human_pos.coords / POSITION_SCALE),
            human_rot: human_yaw_deg / YAW_SCALE,
            target_pos: Xyz::from_vec(target_pos.coords / POSITION_SCALE),
            target_to_human: Xyz::from_vec((target_pos - human_pos) / POSITION_SCALE),
            image: files[0].into(),
            motion: files[1].into(),
            audio: files[2].into(),
        }
    }

    /// The person's position in metres.
    pub fn human_position(&self) -> Point3<f32> {
        Point3::from(self.human_pos.vec() * POSITION_SCALE)
    }

    /// The person's yaw in degrees (clockwise from above, 0 faces +z).
    pub fn human_yaw_deg(&self) -> f32 {
        self.human_rot * YAW_SCALE
    }

    /// The target's position in metres.
    pub fn target_position(&self) -> Point3<f32> {
        Point3::from(self.target_pos.vec() * POSITION_SCALE)
    }

    /// Target minus person, in metres (the field `targetToHuman`).
    pub fn target_offset(&self) -> Vector3<f32> {
        self.target_to_human.vec() * POSITION_SCALE
    }

    /// Parses metadata JSON; `file` names the source in errors.
    pub fn from_json(text: &str, file: &str) -> Result<Metadata, MotionFileError> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let de = &mut serde_json::Deserializer::from_str(text);
        let m: Metadata = serde_path_to_error::deserialize(de).map_err(|e| MotionFileError::Field {
            file: file.to_string(),
            field: e.path().to_string(),
            message: e.inner().to_string(),
        })?;
        let finite =
            [m.human_pos, m.target_pos, m.target_to_human].iter().all(|p| p.vec().iter().all(|v| v.is_finite()));
        if !finite || !m.human_rot.is_finite() {
            return Err(MotionFileError::Field {
                file: file.into(),
                field: "humanPos".into(),
                message: "positions and rotation must be finite".into(),
            });
        }
        Ok(m)
    }

    pub fn load(path: &Path) -> Result<Metadata, MotionFileError> {
        let file = path.display().to_string();
        let text =
            std::fs::read_to_string(path).map_err(|reason| MotionFileError::Io { file: file.clone(), reason })?;
        Metadata::from_json(&text, &file)
    }

    /// JSON in the recorder's layout: 4-space indentation, no final newline.
    pub fn to_json(&self) -> String {
        let mut buf = Vec::new();
        let fmt = serde_json::ser::PrettyFormatter::with_indent(b"    ");
        let mut ser = serde_json::Serializer::with_formatter(&mut buf, fmt);
        self.serialize(&mut ser).expect("metadata serialises");
        String::from_utf8(buf).expect("JSON is UTF-8")
    }

    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        farm::files::write_atomic(path, self.to_json().as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SAMPLE_CSV: &str =
        concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/gond-sample/2021-05-04_13-22-28_mocap.csv");
    const SAMPLE_JSON: &str =
        concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/gond-sample/2021-05-04_13-22-28_mocap.json");

    #[test]
    fn sample_csv_round_trips_bit_exactly() {
        let bytes = std::fs::read(SAMPLE_CSV).unwrap();
        let m = read_csv(Path::new(SAMPLE_CSV)).unwrap();
        assert_eq!(m.frame(0)[0], -0.056);
        assert_eq!(m.frame(0)[24], 0.934);
        assert!(to_csv(&m).as_bytes() == bytes.as_slice(), "written form differs from the recording");
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("motion.csv");
        write_csv(&p, &m).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), bytes);
        let mut bad = m.clone();
        bad.frame_mut(3)[7] = f32::NAN;
        assert!(write_csv(&d.path().join("nan.csv"), &bad).is_err());
    }

    #[test]
    fn value_format_is_the_recorders() {
        for (v, s) in [
            (0.0, "0"),
            (-0.0, "0"),
            (-0.0004, "0"),
            (1.0, "1"),
            (-1.0, "-1"),
            (0.6, "0.6"),
            (-0.056, "-0.056"),
            (0.12345, "0.123"),
            (12.5, "12.5"),
        ] {
            assert_eq!(format_value(v), s, "{v}");
        }
        // Any 3-decimal value survives write → read unchanged.
        for k in -1000..=1000 {
            let v: f32 = format!("{}", k as f32 / 1000.0).parse().unwrap();
            assert_eq!(format_value(v).parse::<f32>().unwrap(), v);
        }
    }

    #[test]
    fn tolerant_reading() {
        let text = std::fs::read_to_string(SAMPLE_CSV).unwrap();
        let want = parse_csv(&text, "a").unwrap();
        // LF line ends, no final line end.
        let lf = text.replace("\r\n", "\n");
        assert_eq!(parse_csv(lf.trim_end(), "b").unwrap(), want);
        // The named header this module writes reads back the same.
        assert_eq!(parse_csv(&to_csv_with(&want, CsvHeader::Names), "n").unwrap(), want);
        assert!(to_csv_with(&want, CsvHeader::Names).starts_with("Spine Front-Back;Spine Left-Right;"));
        // Named header, trailing separators, decimal commas.
        let mut lines: Vec<String> = lf.lines().map(String::from).collect();
        lines[0] = MUSCLE_NAMES.join(";");
        lines[1].push(';');
        lines[2] = lines[2].replace('.', ",");
        assert_eq!(parse_csv(&lines.join("\n"), "c").unwrap(), want);
    }

    fn err(text: &str) -> String {
        parse_csv(text, "motion.csv").unwrap_err().to_string()
    }

    #[test]
    fn bad_csv_names_file_line_and_column() {
        let text = std::fs::read_to_string(SAMPLE_CSV).unwrap();
        let lines: Vec<&str> = text.split("\r\n").collect();
        // 99 rows.
        let short = lines[..100].join("\r\n") + "\r\n";
        let e = err(&short);
        assert!(e.starts_with("motion.csv: line 101:") && e.contains("ends after 99"), "{e}");
        // Wrong column count on row 5 (line 6).
        let mut l: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
        l[5] = l[5].rsplit_once(';').unwrap().0.to_string();
        let e = err(&l.join("\r\n"));
        assert!(e.starts_with("motion.csv: line 6:") && e.contains("found 94"), "{e}");
        // A non-number in column 12 of line 4.
        let mut l: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
        let mut cells: Vec<&str> = l[3].split(';').collect();
        cells[11] = "abc";
        l[3] = cells.join(";");
        let e = err(&l.join("\r\n"));
        assert!(e.starts_with("motion.csv: line 4, column 12 (Neck Turn Left-Right):") && e.contains("`abc`"), "{e}");
        // 101 rows, a bad header, an empty file, NaN, a blank line in the middle.
        let long = text.clone() + lines[1] + "\r\n";
        assert!(err(&long).starts_with("motion.csv: line 102:"));
        assert!(err(&text.replacen("0;1;2", "0;2;1", 1)).starts_with("motion.csv: line 1:"));
        assert!(err("").starts_with("motion.csv: line 1:"));
        assert!(err(&text.replacen("-0.056", "NaN", 1)).contains("line 2, column 1"));
        let gap = text.replacen("\r\n", "\r\n\r\n", 3);
        assert!(err(&gap).starts_with("motion.csv: line 2: empty line"), "{}", err(&gap));
        // A missing file names the file.
        let e = read_csv(Path::new("/nonexistent/motion.csv")).unwrap_err().to_string();
        assert!(e.starts_with("/nonexistent/motion.csv: cannot read"), "{e}");
    }

    #[test]
    fn sample_metadata_loads_in_world_units_and_writes_back() {
        let m = Metadata::load(Path::new(SAMPLE_JSON)).unwrap();
        assert_eq!(m.target_type, "Cup");
        assert_eq!(m.scene_num, 1);
        assert!((m.human_yaw_deg() - 180.0).abs() < 1e-4);
        let h = m.human_position();
        assert!((h.z - 1.819676).abs() < 1e-5 && h.y == 0.0);
        let off = m.target_offset();
        let direct = m.target_position() - h;
        assert!((off - direct).norm() < 1e-4, "targetToHuman is target minus person");
        // Written back in the original layout, it reads back identical and keeps field order.
        let json = m.to_json();
        assert!(
            json.starts_with("{\n    \"instruction\": \"go to is a cup\",\n    \"sceneType\": \"Kitchen\","),
            "{json}"
        );
        assert!(!json.ends_with('\n'));
        assert_eq!(Metadata::from_json(&json, "x").unwrap(), m);
        let original: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(SAMPLE_JSON).unwrap()).unwrap();
        let ours: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(
            original.as_object().unwrap().keys().collect::<Vec<_>>(),
            ours.as_object().unwrap().keys().collect::<Vec<_>>()
        );
        // Built from world units it stores the recorder's scaling.
        let n = Metadata::new(
            "go to the cup",
            "Kitchen",
            1,
            "Cup",
            h,
            180.0,
            m.target_position(),
            ["i.png", "m.csv", "a.wav"],
        );
        assert!((n.human_rot - 0.5).abs() < 1e-6);
        assert!((n.target_to_human.z - m.target_to_human.z).abs() < 1e-6);
    }

    #[test]
    fn bad_metadata_names_the_field() {
        let text = std::fs::read_to_string(SAMPLE_JSON).unwrap();
        let e = Metadata::from_json(&text.replace("\"humanRot\": 0.5", "\"humanRot\": \"half\""), "meta.json")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("meta.json: field `humanRot`"), "{e}");
        let e = Metadata::from_json(&text.replace("\"y\": 0.0", "\"w\": 0.0"), "meta.json").unwrap_err().to_string();
        assert!(e.contains("humanPos"), "{e}");
    }
}
