//! TensorBoard event files (`RUN/tb/events.out.tfevents.*`): scalars, PNG images and Markdown
//! text, readable by TensorBoard and anything that syncs its files (W&B).
//!
//! No maintained Rust crate writes them, and the format is small: a TFRecord file (each record
//! is its length, the length's masked CRC32C, the bytes, their masked CRC32C) of `Event`
//! protobuf messages. The few messages used are encoded here by hand, field by field, from
//! tensorflow/core/util/event.proto and tensorflow/core/framework/summary.proto.
//!
//! Each process writes its own file (one per role: `train`, `farm`, `eval-test`, ...); TensorBoard
//! reads every file of a folder as one run.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

/// An open event file.
#[derive(Debug)]
pub struct EventWriter {
    path: PathBuf,
    file: File,
}

impl EventWriter {
    /// Creates a new event file for `role` in `dir` (made if missing), starting with the
    /// version record every reader expects first.
    pub fn create(dir: &Path, role: &str) -> std::io::Result<EventWriter> {
        std::fs::create_dir_all(dir)?;
        let now = SystemTime::now().duration_since(UNIX_EPOCH).unwrap_or_default();
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
        let host = host.trim();
        // TensorFlow's pattern (time, host, pid, a counter of the process's files), plus the role
        static FILES: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let name = format!(
            "events.out.tfevents.{}.{}.{}.{}.{role}",
            now.as_secs(),
            if host.is_empty() { "localhost" } else { host },
            std::process::id(),
            FILES.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
        );
        let path = dir.join(name);
        let file = std::fs::OpenOptions::new().create_new(true).append(true).open(&path)?;
        let mut w = EventWriter { path, file };
        w.write_event(0, |e| e.string(3, "brain.Event:2"))?;
        Ok(w)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// One record holding every `(tag, value)` at `step`.
    pub fn scalars(&mut self, step: i64, values: &[(&str, f64)]) -> std::io::Result<()> {
        if values.is_empty() {
            return Ok(());
        }
        self.write_event(step, |e| {
            e.message(5, |summary| {
                for (tag, v) in values {
                    summary.message(1, |value| {
                        value.string(1, tag);
                        value.float(2, *v as f32);
                    });
                }
            })
        })
    }

    /// A PNG image (its bytes as written to disk) of `width` × `height` pixels.
    pub fn image_png(&mut self, tag: &str, step: i64, png: &[u8], width: u32, height: u32) -> std::io::Result<()> {
        self.write_event(step, |e| {
            e.message(5, |summary| {
                summary.message(1, |value| {
                    value.string(1, tag);
                    value.message(4, |image| {
                        image.varint(1, height as u64);
                        image.varint(2, width as u64);
                        // RGBA: what plotters' PNGs hold; TensorBoard decodes the PNG anyway
                        image.varint(3, 4);
                        image.bytes(4, png);
                    });
                })
            })
        })
    }

    /// Markdown text (TensorBoard's text plugin renders it), e.g. the run's configuration.
    pub fn text(&mut self, tag: &str, step: i64, markdown: &str) -> std::io::Result<()> {
        self.write_event(step, |e| {
            e.message(5, |summary| {
                summary.message(1, |value| {
                    value.string(1, tag);
                    // SummaryMetadata { plugin_data { plugin_name: "text" } }
                    value.message(9, |meta| meta.message(1, |plugin| plugin.string(1, "text")));
                    // TensorProto { dtype: DT_STRING, tensor_shape: {}, string_val: [markdown] }
                    value.message(8, |tensor| {
                        tensor.varint(1, 7);
                        tensor.message(2, |_| {});
                        tensor.bytes(8, markdown.as_bytes());
                    });
                })
            })
        })
    }

    /// Marks a restart from a checkpoint: readers drop what was recorded at `step` or later by an
    /// earlier process of the run (the updates after that checkpoint are done again).
    pub fn restart_at(&mut self, step: i64) -> std::io::Result<()> {
        // SessionLog { status: START }
        self.write_event(step, |e| e.message(7, |log| log.varint(1, 1)))
    }

    fn write_event(&mut self, step: i64, body: impl FnOnce(&mut Proto)) -> std::io::Result<()> {
        let wall = SystemTime::now().duration_since(UNIX_EPOCH).unwrap_or_default().as_secs_f64();
        let mut e = Proto::default();
        e.double(1, wall);
        e.varint(2, step as u64);
        body(&mut e);
        // One write per record: a reader never sees half a record unless the process dies in it,
        // and TensorBoard stops at a truncated last record.
        self.file.write_all(&record(&e.0))
    }
}

/// One TFRecord: length, masked CRC of the length, data, masked CRC of the data.
fn record(data: &[u8]) -> Vec<u8> {
    let len = (data.len() as u64).to_le_bytes();
    let mut out = Vec::with_capacity(data.len() + 16);
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc(&len).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked_crc(data).to_le_bytes());
    out
}

/// TFRecord's masked CRC32C (a CRC of data that holds CRCs is not itself a good CRC).
fn masked_crc(data: &[u8]) -> u32 {
    let c = crc32c::crc32c(data);
    c.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// A protobuf message being encoded: fields appended in order.
#[derive(Default)]
struct Proto(Vec<u8>);

impl Proto {
    fn key(&mut self, field: u32, wire: u32) {
        self.raw_varint(((field << 3) | wire) as u64);
    }

    fn raw_varint(&mut self, mut v: u64) {
        while v >= 0x80 {
            self.0.push((v as u8) | 0x80);
            v >>= 7;
        }
        self.0.push(v as u8);
    }

    fn varint(&mut self, field: u32, v: u64) {
        self.key(field, 0);
        self.raw_varint(v);
    }

    fn double(&mut self, field: u32, v: f64) {
        self.key(field, 1);
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn float(&mut self, field: u32, v: f32) {
        self.key(field, 5);
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn bytes(&mut self, field: u32, b: &[u8]) {
        self.key(field, 2);
        self.raw_varint(b.len() as u64);
        self.0.extend_from_slice(b);
    }

    fn string(&mut self, field: u32, s: &str) {
        self.bytes(field, s.as_bytes());
    }

    fn message(&mut self, field: u32, fill: impl FnOnce(&mut Proto)) {
        let mut m = Proto::default();
        fill(&mut m);
        self.bytes(field, &m.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The CRC-32C check value (RFC 3720's "123456789") and TFRecord's mask of it.
    #[test]
    fn the_record_checksum_is_masked_crc32c() {
        assert_eq!(crc32c::crc32c(b"123456789"), 0xe306_9283);
        assert_eq!(masked_crc(b"123456789"), 0xe306_9283u32.rotate_right(15).wrapping_add(0xa282_ead8));
    }

    /// A scalar event, byte for byte as protobuf encodes it (checked against the Python reader
    /// in tests/python/read_tensorboard.py through the suite's end-to-end test).
    #[test]
    fn a_scalar_event_encodes_field_by_field() {
        let mut e = Proto::default();
        e.double(1, 1.5);
        e.varint(2, 300);
        e.message(5, |s| {
            s.message(1, |v| {
                v.string(1, "a");
                v.float(2, 2.0);
            })
        });
        let mut golden = vec![0x09];
        golden.extend_from_slice(&1.5f64.to_le_bytes());
        golden.extend_from_slice(&[0x10, 0xac, 0x02]); // step 300 as a varint
        golden.extend_from_slice(&[0x2a, 0x0a, 0x0a, 0x08, 0x0a, 0x01, b'a', 0x15]);
        golden.extend_from_slice(&2.0f32.to_le_bytes());
        assert_eq!(e.0, golden);
    }

    #[test]
    fn records_frame_each_event_with_its_length_and_checksums() {
        let d = tempfile::tempdir().unwrap();
        let mut w = EventWriter::create(&d.path().join("tb"), "train").unwrap();
        w.scalars(10, &[("losses/value", 0.5), ("charts/sr", 0.25)]).unwrap();
        w.image_png("charts/curves", 10, &[1, 2, 3], 2, 1).unwrap();
        w.text("config", 0, "`lr = 3e-4`").unwrap();
        w.restart_at(11).unwrap();
        assert!(w.path().file_name().unwrap().to_string_lossy().starts_with("events.out.tfevents."));
        let bytes = std::fs::read(w.path()).unwrap();
        let mut at = 0;
        let mut records = 0;
        while at < bytes.len() {
            let len_bytes = &bytes[at..at + 8];
            let len = u64::from_le_bytes(len_bytes.try_into().unwrap()) as usize;
            assert_eq!(u32::from_le_bytes(bytes[at + 8..at + 12].try_into().unwrap()), masked_crc(len_bytes));
            let data = &bytes[at + 12..at + 12 + len];
            assert_eq!(u32::from_le_bytes(bytes[at + 12 + len..at + 16 + len].try_into().unwrap()), masked_crc(data));
            at += 16 + len;
            records += 1;
        }
        assert_eq!((at, records), (bytes.len(), 5), "version + 4 events, nothing after");
    }
}
