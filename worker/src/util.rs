//! Small helpers every role uses: seeded random streams and atomic file writes.

use std::io::Write;
use std::path::Path;

use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::SeedableRng;

/// DejaVu Sans (Bitstream Vera licence, `worker/assets/DejaVuSans-LICENSE.txt`), compiled in so
/// that plots and maps draw the same text on machines without system fonts.
pub const FONT_TTF: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// A random stream for `key` under the run's `seed`. The same (seed, key) always gives the
/// same stream, whatever thread or order asks for it; different keys give independent streams.
pub fn rng(seed: u64, key: &[u64]) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(mix(seed, key))
}

/// Folds a key into a seed (SplitMix64 finaliser per word), for when a plain u64 seed is needed.
pub fn mix(seed: u64, key: &[u64]) -> u64 {
    let mut h = splitmix(seed ^ 0x9E37_79B9_7F4A_7C15);
    for &k in key {
        h = splitmix(h ^ splitmix(k.wrapping_add(0x632B_E59B_D9B4_E019)));
    }
    h
}

fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Writes `bytes` to `path` so that a reader sees either the old file or the whole new one:
/// write a temporary file beside it, fsync, rename over.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)?;
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a: Vec<u32> = (0..4).map(|_| 0).scan(rng(7, &[1, 2]), |r, _| Some(r.random())).collect();
        let b: Vec<u32> = (0..4).map(|_| 0).scan(rng(7, &[1, 2]), |r, _| Some(r.random())).collect();
        let c: Vec<u32> = (0..4).map(|_| 0).scan(rng(7, &[2, 1]), |r, _| Some(r.random())).collect();
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn atomic_write_replaces() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.json");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1);
    }
}
