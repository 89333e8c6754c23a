//! What travels between the bridges, key by key and byte by byte: the key expressions of a run,
//! and observations (`[codec][token][header][payload]`) and actions (`[token][message]`) as
//! bytes.

use shm_schema::{ActionMsg, ObsHeader};

// The key expressions of a run (the module doc of `remote` says who puts what on each).
pub(super) fn obs_key(run: &str, slot: u32) -> String {
    format!("gesthor/{run}/obs/{slot}")
}
pub(super) fn act_key(run: &str, slot: u32) -> String {
    format!("gesthor/{run}/act/{slot}")
}
pub(super) fn learner_key(run: &str) -> String {
    format!("gesthor/{run}/learner")
}
pub(super) fn host_key(run: &str, token: u64) -> String {
    format!("gesthor/{run}/host/{token:016x}")
}
/// Every slot's observations, actions or host of a run.
pub(super) fn obs_key_all(run: &str) -> String {
    format!("gesthor/{run}/obs/*")
}
pub(super) fn act_key_all(run: &str) -> String {
    format!("gesthor/{run}/act/*")
}
pub(super) fn host_key_all(run: &str) -> String {
    format!("gesthor/{run}/host/*")
}
/// The learner says it is about to reopen its listener (hosts wait for it to come back).
pub(super) fn reopen_key(run: &str) -> String {
    format!("gesthor/{run}/reopen")
}
/// The slot at the end of an obs/act key.
pub(super) fn slot_of(key: &str) -> Option<u32> {
    key.rsplit('/').next()?.parse().ok()
}
/// The grant token at the end of a host key.
pub(super) fn token_of(key: &str) -> Option<u64> {
    u64::from_str_radix(key.rsplit('/').next()?, 16).ok()
}

/// Encoding of an observation on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Codec {
    Raw = 0,
    Lz4 = 1,
    /// Zstandard at level 1: smaller than LZ4, slower to make.
    Zstd = 2,
}

/// No observation decompresses to more than this (a damaged or hostile size field stops here).
const MAX_PAYLOAD: usize = 1 << 28;

const HEADER_BYTES: usize = std::mem::size_of::<ObsHeader>();
const ACT_BYTES: usize = std::mem::size_of::<ActionMsg>();

fn as_bytes<T: Copy>(v: &T) -> &[u8] {
    // SAFETY: T is one of the schema's #[repr(C)] plain-data messages (integers, floats and
    // arrays of them, padding spelled out as fields), so every byte is initialised.
    unsafe { std::slice::from_raw_parts(v as *const T as *const u8, std::mem::size_of::<T>()) }
}

fn from_bytes<T: Copy>(b: &[u8]) -> T {
    assert_eq!(b.len(), std::mem::size_of::<T>());
    // SAFETY: the length matches and every bit pattern is a valid value of these plain-data
    // messages; the receiver checks magic, version and shape before trusting one.
    unsafe { std::ptr::read_unaligned(b.as_ptr() as *const T) }
}

/// `[codec][token][header][payload]`, the payload LZ4-compressed (size prepended) with `Lz4`.
pub fn encode_obs(codec: Codec, token: u64, header: &ObsHeader, payload: &[u8]) -> Vec<u8> {
    let body = match codec {
        Codec::Raw => std::borrow::Cow::Borrowed(payload),
        Codec::Lz4 => std::borrow::Cow::Owned(lz4_flex::compress_prepend_size(payload)),
        Codec::Zstd => std::borrow::Cow::Owned(zstd::bulk::compress(payload, 1).expect("compressing into a Vec")),
    };
    let mut out = Vec::with_capacity(9 + HEADER_BYTES + body.len());
    out.push(codec as u8);
    out.extend_from_slice(&token.to_le_bytes());
    out.extend_from_slice(as_bytes(header));
    out.extend_from_slice(&body);
    out
}

/// The inverse of [`encode_obs`]; an error says what is wrong with the message.
pub fn decode_obs(bytes: &[u8]) -> Result<(u64, ObsHeader, std::borrow::Cow<'_, [u8]>), String> {
    if bytes.len() < 9 + HEADER_BYTES {
        return Err(format!("{} bytes, shorter than a header", bytes.len()));
    }
    let token = u64::from_le_bytes(bytes[1..9].try_into().expect("8 bytes"));
    let header: ObsHeader = from_bytes(&bytes[9..9 + HEADER_BYTES]);
    let body = &bytes[9 + HEADER_BYTES..];
    let payload = match bytes[0] {
        0 => std::borrow::Cow::Borrowed(body),
        1 => std::borrow::Cow::Owned(lz4_flex::decompress_size_prepended(body).map_err(|e| format!("lz4: {e}"))?),
        2 => std::borrow::Cow::Owned(zstd::bulk::decompress(body, MAX_PAYLOAD).map_err(|e| format!("zstd: {e}"))?),
        c => return Err(format!("unknown codec {c}")),
    };
    Ok((token, header, payload))
}

pub(super) fn encode_act(token: u64, m: &ActionMsg) -> Vec<u8> {
    let mut out = token.to_le_bytes().to_vec();
    out.extend_from_slice(as_bytes(m));
    out
}

pub(super) fn decode_act(bytes: &[u8]) -> Option<(u64, ActionMsg)> {
    (bytes.len() == 8 + ACT_BYTES)
        .then(|| (u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")), from_bytes(&bytes[8..])))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn observations_and_actions_survive_the_wire() {
        let header = ObsHeader { magic: shm_schema::OBS_MAGIC, worker_id: 5, step: 77, ..Default::default() };
        let payload: Vec<u8> = (0..10_000u32).map(|i| (i % 7) as u8).collect();
        for codec in [Codec::Raw, Codec::Lz4, Codec::Zstd] {
            let bytes = encode_obs(codec, 42, &header, &payload);
            let (token, h, p) = decode_obs(&bytes).unwrap();
            assert_eq!((token, h, &p[..]), (42, header, &payload[..]), "{codec:?}");
        }
        for codec in [Codec::Lz4, Codec::Zstd] {
            assert!(encode_obs(codec, 1, &header, &payload).len() < payload.len() / 4, "{codec:?} compresses");
        }
        assert!(decode_obs(&[0; 20]).is_err());
        let m = ActionMsg { worker_id: 5, generation: 65536, step: 77, ..Default::default() };
        assert_eq!(decode_act(&encode_act(9, &m)), Some((9, m)));
    }
}
