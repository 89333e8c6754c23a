//! Reads the state dicts that PyTorch's `torch.save` writes (`.pth`/`.pt`), without Python.
//!
//! libtorch's own unpickler refuses them: a `state_dict()` is an `OrderedDict` carrying a
//! `_metadata` attribute, which it cannot rebuild. The format is small enough to read here: a
//! zip archive holding `<name>/data.pkl` — a pickle (protocol 2) whose tensors are
//! `torch._utils._rebuild_tensor_v2(storage, offset, size, stride, ...)` calls and whose storages
//! are persistent ids `('storage', torch.FloatStorage, key, location, numel)` — and one raw
//! little-endian file per storage, `<name>/data/<key>`. Only what state dicts use is
//! understood; anything else is an error that says what was found.

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

use tch::{Kind, Tensor};

#[derive(Clone, Debug)]
#[allow(dead_code, reason = "payloads are shown in error messages through Debug")]
enum Value {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    Bytes(Vec<u8>),
    Tuple(Vec<Value>),
    List(Vec<Value>),
    Dict(Vec<(Value, Value)>),
    /// `module.name`, e.g. `torch.FloatStorage`.
    Global(String),
    Storage {
        kind: Kind,
        key: String,
    },
    Tensor {
        kind: Kind,
        key: String,
        offset: i64,
        size: Vec<i64>,
        stride: Vec<i64>,
    },
    /// Something built by a callable we do not know (kept only to report it).
    Object(String),
    Mark,
}

fn storage_kind(class: &str) -> Option<Kind> {
    Some(match class {
        "torch.FloatStorage" => Kind::Float,
        "torch.DoubleStorage" => Kind::Double,
        "torch.HalfStorage" => Kind::Half,
        "torch.BFloat16Storage" => Kind::BFloat16,
        "torch.LongStorage" => Kind::Int64,
        "torch.IntStorage" => Kind::Int,
        "torch.ShortStorage" => Kind::Int16,
        "torch.CharStorage" => Kind::Int8,
        "torch.ByteStorage" => Kind::Uint8,
        "torch.BoolStorage" => Kind::Bool,
        _ => return None,
    })
}

fn ints(v: &Value, what: &str) -> Result<Vec<i64>, String> {
    match v {
        Value::Tuple(xs) | Value::List(xs) => xs
            .iter()
            .map(|x| match x {
                Value::Int(i) => Ok(*i),
                other => Err(format!("{what}: expected integers, found {other:?}")),
            })
            .collect(),
        other => Err(format!("{what}: expected a tuple, found {other:?}")),
    }
}

/// The pickle machine, reduced to the opcodes of protocols 2–4 that state dicts use.
fn unpickle(data: &[u8]) -> Result<Value, String> {
    let mut stack: Vec<Value> = Vec::new();
    let mut memo: HashMap<u32, Value> = HashMap::new();
    let mut pos = 0usize;
    let take = |pos: &mut usize, n: usize| -> Result<&[u8], String> {
        let s = data.get(*pos..*pos + n).ok_or("pickle ends early")?;
        *pos += n;
        Ok(s)
    };
    let line = |pos: &mut usize| -> Result<String, String> {
        let end = data[*pos..].iter().position(|b| *b == b'\n').ok_or("pickle ends early")?;
        let s = String::from_utf8_lossy(&data[*pos..*pos + end]).into_owned();
        *pos += end + 1;
        Ok(s)
    };
    let pop = |stack: &mut Vec<Value>| stack.pop().ok_or_else(|| "pickle stack underflow".to_string());
    let pop_mark = |stack: &mut Vec<Value>| -> Result<Vec<Value>, String> {
        let at = stack.iter().rposition(|v| matches!(v, Value::Mark)).ok_or("pickle: no mark")?;
        let items = stack.split_off(at + 1);
        stack.pop();
        Ok(items)
    };
    let u32le = |b: &[u8]| u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    loop {
        let op = *take(&mut pos, 1)?.first().unwrap();
        match op {
            0x80 => {
                take(&mut pos, 1)?;
            } // PROTO
            0x95 => {
                take(&mut pos, 8)?;
            } // FRAME
            b'.' => return pop(&mut stack), // STOP
            b'(' => stack.push(Value::Mark),
            b'N' => stack.push(Value::None),
            0x88 => stack.push(Value::Bool(true)),
            0x89 => stack.push(Value::Bool(false)),
            b'K' => stack.push(Value::Int(take(&mut pos, 1)?[0] as i64)),
            b'M' => {
                let b = take(&mut pos, 2)?;
                stack.push(Value::Int(u16::from_le_bytes([b[0], b[1]]) as i64));
            }
            b'J' => stack.push(Value::Int(u32le(take(&mut pos, 4)?) as i32 as i64)),
            0x8a => {
                // LONG1: little-endian two's complement of n bytes
                let n = take(&mut pos, 1)?[0] as usize;
                let b = take(&mut pos, n)?;
                if n > 8 {
                    return Err("pickle: integer wider than 64 bits".into());
                }
                let mut v: i64 = 0;
                for (i, byte) in b.iter().enumerate() {
                    v |= (*byte as i64) << (8 * i);
                }
                if n > 0 && n < 8 && b[n - 1] & 0x80 != 0 {
                    v -= 1i64 << (8 * n);
                }
                stack.push(Value::Int(v));
            }
            b'G' => {
                let b = take(&mut pos, 8)?;
                stack.push(Value::Float(f64::from_be_bytes(b.try_into().unwrap())));
            }
            b'X' => {
                let n = u32le(take(&mut pos, 4)?) as usize;
                stack.push(Value::Str(String::from_utf8_lossy(take(&mut pos, n)?).into_owned()));
            }
            0x8c => {
                let n = take(&mut pos, 1)?[0] as usize;
                stack.push(Value::Str(String::from_utf8_lossy(take(&mut pos, n)?).into_owned()));
            }
            b'U' => {
                let n = take(&mut pos, 1)?[0] as usize;
                stack.push(Value::Str(String::from_utf8_lossy(take(&mut pos, n)?).into_owned()));
            }
            b'T' | b'B' => {
                let n = u32le(take(&mut pos, 4)?) as usize;
                let bytes = take(&mut pos, n)?.to_vec();
                stack.push(if op == b'T' {
                    Value::Str(String::from_utf8_lossy(&bytes).into_owned())
                } else {
                    Value::Bytes(bytes)
                });
            }
            b'C' => {
                let n = take(&mut pos, 1)?[0] as usize;
                stack.push(Value::Bytes(take(&mut pos, n)?.to_vec()));
            }
            b'}' => stack.push(Value::Dict(Vec::new())),
            b']' => stack.push(Value::List(Vec::new())),
            b')' => stack.push(Value::Tuple(Vec::new())),
            b't' => {
                let items = pop_mark(&mut stack)?;
                stack.push(Value::Tuple(items));
            }
            0x85..=0x87 => {
                let n = (op - 0x84) as usize;
                if stack.len() < n {
                    return Err("pickle stack underflow".into());
                }
                let items = stack.split_off(stack.len() - n);
                stack.push(Value::Tuple(items));
            }
            b'q' => {
                let k = take(&mut pos, 1)?[0] as u32;
                memo.insert(k, stack.last().cloned().ok_or("pickle: memo of empty stack")?);
            }
            b'r' => {
                let k = u32le(take(&mut pos, 4)?);
                memo.insert(k, stack.last().cloned().ok_or("pickle: memo of empty stack")?);
            }
            0x94 => {
                let k = memo.len() as u32;
                memo.insert(k, stack.last().cloned().ok_or("pickle: memo of empty stack")?);
            }
            b'h' | b'j' => {
                let k = if op == b'h' { take(&mut pos, 1)?[0] as u32 } else { u32le(take(&mut pos, 4)?) };
                stack.push(memo.get(&k).cloned().ok_or_else(|| format!("pickle: memo {k} missing"))?);
            }
            b'c' => {
                let module = line(&mut pos)?;
                let name = line(&mut pos)?;
                stack.push(Value::Global(format!("{module}.{name}")));
            }
            0x93 => {
                let name = pop(&mut stack)?;
                let module = pop(&mut stack)?;
                match (module, name) {
                    (Value::Str(m), Value::Str(n)) => stack.push(Value::Global(format!("{m}.{n}"))),
                    _ => return Err("pickle: STACK_GLOBAL needs two strings".into()),
                }
            }
            b'Q' => {
                // BINPERSID: ('storage', storage class, key, location, numel)
                let pid = pop(&mut stack)?;
                let Value::Tuple(t) = &pid else { return Err(format!("pickle: persistent id {pid:?}")) };
                match t.as_slice() {
                    [Value::Str(tag), Value::Global(class), Value::Str(key), ..] if tag == "storage" => {
                        let kind = storage_kind(class).ok_or_else(|| format!("unsupported storage type {class}"))?;
                        stack.push(Value::Storage { kind, key: key.clone() });
                    }
                    _ => return Err(format!("pickle: unexpected persistent id {pid:?}")),
                }
            }
            b'R' | 0x81 => {
                let args = pop(&mut stack)?;
                let callable = pop(&mut stack)?;
                stack.push(reduce(callable, args)?);
            }
            b'b' => {
                // BUILD: the OrderedDict's `_metadata` and the like; the value stays as it is
                pop(&mut stack)?;
            }
            b's' => {
                let v = pop(&mut stack)?;
                let k = pop(&mut stack)?;
                match stack.last_mut() {
                    Some(Value::Dict(d)) => d.push((k, v)),
                    _ => return Err("pickle: SETITEM on a non-dict".into()),
                }
            }
            b'u' => {
                let items = pop_mark(&mut stack)?;
                match stack.last_mut() {
                    Some(Value::Dict(d)) => {
                        let mut it = items.into_iter();
                        while let (Some(k), Some(v)) = (it.next(), it.next()) {
                            d.push((k, v));
                        }
                    }
                    _ => return Err("pickle: SETITEMS on a non-dict".into()),
                }
            }
            b'a' => {
                let v = pop(&mut stack)?;
                match stack.last_mut() {
                    Some(Value::List(l)) => l.push(v),
                    _ => return Err("pickle: APPEND on a non-list".into()),
                }
            }
            b'e' => {
                let items = pop_mark(&mut stack)?;
                match stack.last_mut() {
                    Some(Value::List(l)) => l.extend(items),
                    _ => return Err("pickle: APPENDS on a non-list".into()),
                }
            }
            other => return Err(format!("pickle opcode 0x{other:02x} at byte {} is not supported", pos - 1)),
        }
    }
}

fn reduce(callable: Value, args: Value) -> Result<Value, String> {
    let Value::Global(name) = &callable else { return Ok(Value::Object(format!("{callable:?}"))) };
    let a = match &args {
        Value::Tuple(a) => a.as_slice(),
        _ => &[],
    };
    Ok(match name.as_str() {
        "collections.OrderedDict" | "builtins.dict" => Value::Dict(Vec::new()),
        "torch._utils._rebuild_tensor_v2" | "torch._utils._rebuild_tensor" => match a {
            [Value::Storage { kind, key }, Value::Int(offset), size, stride, ..] => Value::Tensor {
                kind: *kind,
                key: key.clone(),
                offset: *offset,
                size: ints(size, "tensor size")?,
                stride: ints(stride, "tensor stride")?,
            },
            _ => return Err(format!("{name}: unexpected arguments {args:?}")),
        },
        // nn.Parameter(tensor, requires_grad, hooks)
        "torch._utils._rebuild_parameter" | "torch._utils._rebuild_parameter_with_state" => {
            a.first().cloned().ok_or("_rebuild_parameter without a tensor")?
        }
        _ => Value::Object(name.clone()),
    })
}

/// The named tensors of a `torch.save` file. A dict nested under `state_dict` or `model` (a
/// training checkpoint) is looked into.
pub fn read_state_dict(path: &Path) -> Result<Vec<(String, Tensor)>, String> {
    let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let mut zip = zip::ZipArchive::new(file).map_err(|e| format!("not a torch.save zip archive ({e})"))?;
    let pkl = (0..zip.len())
        .filter_map(|i| zip.by_index(i).ok().map(|f| f.name().to_string()))
        .find(|n| n.ends_with("data.pkl"))
        .ok_or("no data.pkl in the archive")?;
    let prefix = pkl.trim_end_matches("data.pkl").to_string();
    let mut read = |name: &str| -> Result<Vec<u8>, String> {
        let mut f = zip.by_name(name).map_err(|e| format!("{name}: {e}"))?;
        let mut buf = Vec::with_capacity(f.size() as usize);
        f.read_to_end(&mut buf).map_err(|e| format!("{name}: {e}"))?;
        Ok(buf)
    };
    if let Ok(order) = read(&format!("{prefix}byteorder"))
        && order != b"little"
    {
        return Err("big-endian torch.save files are not supported".into());
    }
    let mut root = unpickle(&read(&pkl)?)?;
    for _ in 0..2 {
        let Value::Dict(items) = &root else { break };
        let nested = items.iter().find_map(|(k, v)| match (k, v) {
            (Value::Str(k), Value::Dict(_)) if k == "state_dict" || k == "model" => Some(v.clone()),
            _ => None,
        });
        match nested {
            Some(v) => root = v,
            None => break,
        }
    }
    let Value::Dict(items) = root else { return Err(format!("the pickle holds {root:?}, not a dict of tensors")) };
    let mut storages: HashMap<String, Tensor> = HashMap::new();
    let mut out = Vec::new();
    for (k, v) in items {
        let Value::Str(name) = k else { continue };
        let Value::Tensor { kind, key, offset, size, stride } = v else { continue };
        if !storages.contains_key(&key) {
            let bytes = read(&format!("{prefix}data/{key}"))?;
            let n = bytes.len() / kind.elt_size_in_bytes();
            let t = Tensor::f_from_data_size(&bytes, &[n as i64], kind).map_err(|e| format!("storage {key}: {e}"))?;
            storages.insert(key.clone(), t);
        }
        let storage = &storages[&key];
        let needed = offset + size.iter().zip(&stride).map(|(s, st)| (s - 1).max(0) * st).sum::<i64>() + 1;
        if size.iter().all(|s| *s > 0) && needed > storage.size()[0] {
            return Err(format!("`{name}` reaches past its storage"));
        }
        let t =
            storage.f_as_strided(size.as_slice(), stride.as_slice(), offset).map_err(|e| format!("`{name}`: {e}"))?;
        out.push((name, t.contiguous()));
    }
    Ok(out)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::io::Write;

    /// Writes what `torch.save(state_dict)` writes (pickle protocol 2, opcode for opcode as
    /// Python's pickler emits it, `OrderedDict` with `_metadata`, stored zip entries).
    pub fn write_torch_save(path: &Path, tensors: &[(&str, Tensor)]) {
        let mut p: Vec<u8> = vec![0x80, 2];
        let global = |p: &mut Vec<u8>, m: &str, n: &str| {
            p.push(b'c');
            p.extend(format!("{m}\n{n}\n").bytes());
        };
        let string = |p: &mut Vec<u8>, s: &str| {
            p.push(b'X');
            p.extend((s.len() as u32).to_le_bytes());
            p.extend(s.bytes());
        };
        let int = |p: &mut Vec<u8>, v: i64| {
            p.push(b'J');
            p.extend((v as i32).to_le_bytes());
        };
        global(&mut p, "collections", "OrderedDict");
        p.extend([b')', b'R', b'(']);
        let mut storages = Vec::new();
        for (i, (name, t)) in tensors.iter().enumerate() {
            let (class, kind) = match t.kind() {
                Kind::Int64 => ("LongStorage", Kind::Int64),
                _ => ("FloatStorage", Kind::Float),
            };
            let t = t.to_kind(kind).contiguous();
            string(&mut p, name);
            global(&mut p, "torch._utils", "_rebuild_tensor_v2");
            p.extend([b'(', b'(']);
            string(&mut p, "storage");
            global(&mut p, "torch", class);
            string(&mut p, &i.to_string());
            string(&mut p, "cpu");
            int(&mut p, t.numel() as i64);
            p.extend([b't', b'Q']);
            int(&mut p, 0);
            let size = t.size();
            let mut stride = vec![1i64; size.len()];
            for d in (0..size.len().saturating_sub(1)).rev() {
                stride[d] = stride[d + 1] * size[d + 1];
            }
            for dims in [&size, &stride] {
                p.push(b'(');
                for d in dims.iter() {
                    int(&mut p, *d);
                }
                p.push(b't');
            }
            p.push(0x89);
            global(&mut p, "collections", "OrderedDict");
            p.extend([b')', b'R', b't', b'R']);
            let mut bytes = vec![0u8; t.numel() * kind.elt_size_in_bytes()];
            t.copy_data_u8(&mut bytes, t.numel());
            storages.push(bytes);
        }
        p.push(b'u');
        // BUILD with {'_metadata': OrderedDict({'': {'version': 1}})}
        p.push(b'}');
        string(&mut p, "_metadata");
        global(&mut p, "collections", "OrderedDict");
        p.extend([b')', b'R']);
        string(&mut p, "");
        p.push(b'}');
        string(&mut p, "version");
        int(&mut p, 1);
        p.extend([b's', b's', b's', b'b', b'.']);

        let mut z = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
        let opt = zip::write::FileOptions::default().compression_method(zip::CompressionMethod::Stored);
        z.start_file("resnet18/data.pkl", opt).unwrap();
        z.write_all(&p).unwrap();
        z.start_file("resnet18/byteorder", opt).unwrap();
        z.write_all(b"little").unwrap();
        for (i, s) in storages.iter().enumerate() {
            z.start_file(format!("resnet18/data/{i}"), opt).unwrap();
            z.write_all(s).unwrap();
        }
        z.start_file("resnet18/version", opt).unwrap();
        z.write_all(b"3\n").unwrap();
        z.finish().unwrap();
    }

    #[test]
    fn reads_a_torch_save_state_dict() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sd.pth");
        let a = Tensor::arange(6, (Kind::Float, tch::Device::Cpu)).view([2, 3]) * 0.5;
        let n = Tensor::from(7i64);
        write_torch_save(&path, &[("a.weight", a.shallow_clone()), ("bn.num_batches_tracked", n)]);
        let got = read_state_dict(&path).unwrap();
        assert_eq!(got.len(), 2);
        assert_eq!(got[0].0, "a.weight");
        assert!(got[0].1.equal(&a));
        assert_eq!(got[1].1.int64_value(&[]), 7);
        assert_eq!(got[1].1.size(), Vec::<i64>::new());
    }

    #[test]
    fn other_files_are_refused_with_a_reason() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.pth");
        std::fs::write(&path, b"hello").unwrap();
        assert!(read_state_dict(&path).unwrap_err().contains("zip"));
        assert!(unpickle(&[0x80, 2, 0xff]).unwrap_err().contains("0xff"));
    }
}
