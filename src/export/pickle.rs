//! A minimal Python pickle writer (protocol 2): strings, ints, floats, lists, dicts and numpy float64,
//! float32 and int8 arrays, enough for GeoTransformer's `metadata/*.pkl` and its `.pth` clouds (pth.rs)
//! without Python in the product path.
//!
//! Arrays use the opcode sequence numpy itself emits for protocol 2 (`ndarray.__reduce__`):
//! `numpy.core.multiarray._reconstruct(numpy.ndarray, (0,), b'b')`, then BUILD with the state
//! `(1, shape, dtype('<f8'), False, raw_bytes)` (`'<f4'`, `'|i1'`), where `dtype` is itself rebuilt with its own BUILD state
//! and the bytes come from `_codecs.encode(<latin-1 text>, 'latin1')` (protocol 2 has no bytes opcode).
//! `numpy.core.multiarray` loads without a warning in numpy 1.x and 2.x. No memo is written.

/// A value to pickle.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    List(Vec<Value>),
    /// A dict with string keys, in this order.
    Dict(Vec<(String, Value)>),
    /// A C-ordered numpy float64 array; `data.len()` is the product of `shape`.
    ArrayF64 { shape: Vec<usize>, data: Vec<f64> },
    /// A C-ordered numpy float32 array.
    ArrayF32 { shape: Vec<usize>, data: Vec<f32> },
    /// A C-ordered numpy int8 array.
    ArrayI8 { shape: Vec<usize>, data: Vec<i8> },
}

const PROTO: u8 = 0x80;
const STOP: u8 = b'.';
const MARK: u8 = b'(';
const NONE: u8 = b'N';
const NEWTRUE: u8 = 0x88;
const NEWFALSE: u8 = 0x89;
const BININT: u8 = b'J';
const BININT1: u8 = b'K';
const BININT2: u8 = b'M';
const LONG1: u8 = 0x8a;
const BINFLOAT: u8 = b'G';
const BINUNICODE: u8 = b'X';
const EMPTY_LIST: u8 = b']';
const APPENDS: u8 = b'e';
const EMPTY_DICT: u8 = b'}';
const SETITEMS: u8 = b'u';
const TUPLE: u8 = b't';
const TUPLE1: u8 = 0x85;
const TUPLE2: u8 = 0x86;
const TUPLE3: u8 = 0x87;
const GLOBAL: u8 = b'c';
const REDUCE: u8 = b'R';
const BUILD: u8 = b'b';

/// Items per APPENDS/SETITEMS batch (as CPython's pickler).
const BATCH: usize = 1000;

/// The protocol-2 pickle of `value` (what `pickle.load` reads back as the same Python object).
pub fn dumps(value: &Value) -> Vec<u8> {
    let mut out = vec![PROTO, 2];
    write_value(&mut out, value);
    out.push(STOP);
    out
}

fn write_value(out: &mut Vec<u8>, v: &Value) {
    match v {
        Value::None => out.push(NONE),
        Value::Bool(b) => out.push(if *b { NEWTRUE } else { NEWFALSE }),
        Value::Int(i) => write_int(out, *i),
        Value::Float(f) => {
            out.push(BINFLOAT);
            out.extend_from_slice(&f.to_be_bytes());
        }
        Value::Str(s) => write_str(out, s),
        Value::List(items) => {
            out.push(EMPTY_LIST);
            for chunk in items.chunks(BATCH) {
                out.push(MARK);
                chunk.iter().for_each(|x| write_value(out, x));
                out.push(APPENDS);
            }
        }
        Value::Dict(items) => {
            out.push(EMPTY_DICT);
            for chunk in items.chunks(BATCH) {
                out.push(MARK);
                for (k, x) in chunk {
                    write_str(out, k);
                    write_value(out, x);
                }
                out.push(SETITEMS);
            }
        }
        Value::ArrayF64 { shape, data } => {
            assert_eq!(shape.iter().product::<usize>(), data.len(), "array data does not match its shape");
            let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
            write_array(out, shape, "f8", "<", &bytes);
        }
        Value::ArrayF32 { shape, data } => {
            assert_eq!(shape.iter().product::<usize>(), data.len(), "array data does not match its shape");
            let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
            write_array(out, shape, "f4", "<", &bytes);
        }
        Value::ArrayI8 { shape, data } => {
            assert_eq!(shape.iter().product::<usize>(), data.len(), "array data does not match its shape");
            let bytes: Vec<u8> = data.iter().map(|&x| x as u8).collect();
            write_array(out, shape, "i1", "|", &bytes); // one byte: no byte order
        }
    }
}

fn write_int(out: &mut Vec<u8>, i: i64) {
    if (0..=0xff).contains(&i) {
        out.extend_from_slice(&[BININT1, i as u8]);
    } else if (0..=0xffff).contains(&i) {
        out.push(BININT2);
        out.extend_from_slice(&(i as u16).to_le_bytes());
    } else if i32::try_from(i).is_ok() {
        out.push(BININT);
        out.extend_from_slice(&(i as i32).to_le_bytes());
    } else {
        // LONG1: little-endian two's complement, 8 bytes always suffice.
        out.extend_from_slice(&[LONG1, 8]);
        out.extend_from_slice(&i.to_le_bytes());
    }
}

fn write_str(out: &mut Vec<u8>, s: &str) {
    out.push(BINUNICODE);
    out.extend_from_slice(&(s.len() as u32).to_le_bytes());
    out.extend_from_slice(s.as_bytes());
}

fn write_global(out: &mut Vec<u8>, module: &str, name: &str) {
    out.push(GLOBAL);
    out.extend_from_slice(format!("{module}\n{name}\n").as_bytes());
}

/// `_codecs.encode(<bytes as latin-1 text>, 'latin1')`, which unpickles to `bytes`.
fn write_bytes(out: &mut Vec<u8>, bytes: &[u8]) {
    write_global(out, "_codecs", "encode");
    let text: String = bytes.iter().map(|&b| b as char).collect();
    write_str(out, &text);
    write_str(out, "latin1");
    out.extend_from_slice(&[TUPLE2, REDUCE]);
}

fn write_tuple_of_ints(out: &mut Vec<u8>, xs: &[usize]) {
    match xs.len() {
        0 => out.push(b')'),
        1..=3 => {
            xs.iter().for_each(|&x| write_int(out, x as i64));
            out.push([TUPLE1, TUPLE2, TUPLE3][xs.len() - 1]);
        }
        _ => {
            out.push(MARK);
            xs.iter().for_each(|&x| write_int(out, x as i64));
            out.push(TUPLE);
        }
    }
}

/// The numpy protocol-2 sequence for a C-ordered array of dtype `code` (`f8`, `f4`, `i1`) with byte
/// order `order` (`<` little-endian, `|` not applicable), `raw` its data in that order.
fn write_array(out: &mut Vec<u8>, shape: &[usize], code: &str, order: &str, raw: &[u8]) {
    write_global(out, "numpy.core.multiarray", "_reconstruct");
    write_global(out, "numpy", "ndarray");
    write_tuple_of_ints(out, &[0]);
    write_bytes(out, b"b");
    out.extend_from_slice(&[TUPLE3, REDUCE]);
    out.push(MARK);
    write_int(out, 1);
    write_tuple_of_ints(out, shape);
    // dtype(code, False, True) with state (3, order, None, None, None, -1, -1, 0).
    write_global(out, "numpy", "dtype");
    write_str(out, code);
    out.extend_from_slice(&[NEWFALSE, NEWTRUE, TUPLE3, REDUCE, MARK]);
    write_int(out, 3);
    write_str(out, order);
    out.extend_from_slice(&[NONE, NONE, NONE]);
    write_int(out, -1);
    write_int(out, -1);
    write_int(out, 0);
    out.extend_from_slice(&[TUPLE, BUILD]);
    out.push(NEWFALSE); // not Fortran-ordered
    write_bytes(out, raw);
    out.extend_from_slice(&[TUPLE, BUILD]);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scalars_and_containers_have_the_cpython_bytes() {
        // pickle.dumps([{'a': 's', 'b': 1, 'c': 0.5}], protocol=2) without the memo (BINPUT) opcodes.
        let v = Value::List(vec![Value::Dict(vec![
            ("a".into(), Value::Str("s".into())),
            ("b".into(), Value::Int(1)),
            ("c".into(), Value::Float(0.5)),
        ])]);
        let x = |c: u8| [b'X', 1, 0, 0, 0, c];
        let want = [
            &[0x80, 2, b']', b'(', b'}', b'('][..],
            &x(b'a'),
            &x(b's'),
            &x(b'b'),
            &[b'K', 1],
            &x(b'c'),
            &[b'G', 0x3f, 0xe0, 0, 0, 0, 0, 0, 0],
            b"ue.",
        ]
        .concat();
        assert_eq!(dumps(&v), want);
    }

    #[test]
    fn ints_pick_the_smallest_opcode() {
        let enc = |i| {
            let mut o = Vec::new();
            write_int(&mut o, i);
            o
        };
        assert_eq!(enc(7), vec![b'K', 7]);
        assert_eq!(enc(300), vec![b'M', 0x2c, 1]);
        assert_eq!(enc(-1), vec![b'J', 0xff, 0xff, 0xff, 0xff]);
        assert_eq!(enc(1 << 40), [&[0x8a, 8][..], &(1i64 << 40).to_le_bytes()].concat());
    }

    #[test]
    fn array_bytes_are_latin1_text_and_end_with_build() {
        let p = dumps(&Value::ArrayF64 { shape: vec![3], data: vec![0.0, 1.0, -2.5] });
        let s = String::from_utf8_lossy(&p);
        assert!(s.contains("numpy.core.multiarray\n_reconstruct\n") && s.contains("numpy\ndtype\n") && s.contains("latin1"));
        assert_eq!(&p[p.len() - 3..], &[TUPLE, BUILD, STOP]);
        // 1.0 = 00..00 f0 3f: the byte 0xf0 becomes the two UTF-8 bytes c3 b0.
        assert!(p.windows(3).any(|w| w == [0xc3, 0xb0, b'?']));
    }
}
