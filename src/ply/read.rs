//! The PLY reader: the vertex positions of ascii or binary (little- or big-endian) PLY files, whatever
//! other elements and properties they carry (fragment clouds of the official 3DMatch benchmark, and
//! what [`super::write`] writes).

use crate::error::{Error, Result};
use crate::geometry::Point;
use std::path::Path;

/// Reads the vertex positions of the PLY file at `path` (see [`decode_ply`]).
pub fn read_ply(path: &Path) -> Result<Vec<Point>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode_ply(&bytes, path)
}

/// Decodes the `x`, `y`, `z` properties of the `vertex` element of a PLY file held in memory (ascii,
/// binary little- or big-endian; any scalar type, stored as f32). Other properties and elements,
/// list properties included, are skipped. `path` only names the file in errors. Fails on a malformed
/// header, a missing vertex element or coordinate, and data shorter than the header announces.
pub fn decode_ply(bytes: &[u8], path: &Path) -> Result<Vec<Point>> {
    let bad = |m: String| Error::input(path, m);
    let (header, body_start) = parse_header(bytes).map_err(bad)?;
    let Some(vi) = header.elements.iter().position(|e| e.name == "vertex") else {
        return Err(bad("PLY has no `element vertex`".into()));
    };
    let vertex = &header.elements[vi];
    let mut xyz = [0usize; 3];
    for (slot, axis) in xyz.iter_mut().zip(["x", "y", "z"]) {
        *slot = vertex
            .props
            .iter()
            .position(|p| p.name == axis && p.list_count.is_none())
            .ok_or_else(|| bad(format!("PLY vertex element has no scalar `{axis}` property")))?;
    }
    let mut body = Body::new(&bytes[body_start..], header.format);
    for e in &header.elements[..vi] {
        for row in 0..e.count {
            skip_row(&mut body, e).map_err(|m| bad(format!("element {} row {row} of {}: {m}", e.name, e.count)))?;
        }
    }
    let mut points = Vec::with_capacity(vertex.count.min(body.bytes.len() / 3 + 1));
    let mut values = vec![0.0f64; vertex.props.len()];
    for row in 0..vertex.count {
        read_row(&mut body, vertex, &mut values)
            .map_err(|m| bad(format!("vertex {row} of {}: {m}", vertex.count)))?;
        points.push(Point::new(values[xyz[0]] as f32, values[xyz[1]] as f32, values[xyz[2]] as f32));
    }
    Ok(points)
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Format {
    Ascii,
    LittleEndian,
    BigEndian,
}

#[derive(Clone, Copy, Debug)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn parse(s: &str) -> std::result::Result<Ty, String> {
        Ok(match s {
            "char" | "int8" => Ty::I8,
            "uchar" | "uint8" => Ty::U8,
            "short" | "int16" => Ty::I16,
            "ushort" | "uint16" => Ty::U16,
            "int" | "int32" => Ty::I32,
            "uint" | "uint32" => Ty::U32,
            "float" | "float32" => Ty::F32,
            "double" | "float64" => Ty::F64,
            _ => return Err(format!("unknown PLY property type `{s}`")),
        })
    }

    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }
}

struct Prop {
    name: String,
    ty: Ty,
    /// For a list property, the type of its length prefix (`ty` is then the item type).
    list_count: Option<Ty>,
}

struct Element {
    name: String,
    count: usize,
    props: Vec<Prop>,
}

struct Header {
    format: Format,
    elements: Vec<Element>,
}

/// Parses the header; returns it and the offset of the first byte after `end_header\n`.
fn parse_header(bytes: &[u8]) -> std::result::Result<(Header, usize), String> {
    let mut pos = 0;
    let mut next_line = || -> Option<&str> {
        let rest = &bytes[pos..];
        let end = rest.iter().position(|&b| b == b'\n')?;
        pos += end + 1;
        std::str::from_utf8(&rest[..end]).ok().map(|l| l.trim_end_matches('\r'))
    };
    if next_line().map(str::trim) != Some("ply") {
        return Err("not a PLY file (no `ply` magic line)".into());
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let line = next_line().ok_or("PLY header is truncated or not text (no `end_header` line)")?;
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["end_header"] => break,
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", f, _version] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::LittleEndian,
                    "binary_big_endian" => Format::BigEndian,
                    _ => return Err(format!("unknown PLY format `{f}`")),
                })
            }
            ["element", name, count] => {
                let count = count.parse().map_err(|_| format!("bad element count in `{line}`"))?;
                elements.push(Element { name: name.to_string(), count, props: Vec::new() });
            }
            ["property", rest @ ..] => {
                let e = elements.last_mut().ok_or_else(|| format!("`{line}` comes before any element"))?;
                let prop = match rest {
                    ["list", count_ty, item_ty, name] => {
                        Prop { name: name.to_string(), ty: Ty::parse(item_ty)?, list_count: Some(Ty::parse(count_ty)?) }
                    }
                    [ty, name] => Prop { name: name.to_string(), ty: Ty::parse(ty)?, list_count: None },
                    _ => return Err(format!("malformed PLY property line `{line}`")),
                };
                e.props.push(prop);
            }
            _ => return Err(format!("unexpected PLY header line `{line}`")),
        }
    }
    let format = format.ok_or("PLY header has no `format` line")?;
    Ok((Header { format, elements }, pos))
}

/// The data after the header: a byte cursor for binary formats, a token stream for ascii.
struct Body<'a> {
    bytes: &'a [u8],
    pos: usize,
    format: Format,
    tokens: std::str::SplitAsciiWhitespace<'a>,
}

impl<'a> Body<'a> {
    fn new(bytes: &'a [u8], format: Format) -> Self {
        // Ascii bodies that are not UTF-8 fail at their first token rather than here.
        let text = if format == Format::Ascii { std::str::from_utf8(bytes).unwrap_or("\u{0}") } else { "" };
        Body { bytes, pos: 0, format, tokens: text.split_ascii_whitespace() }
    }

    fn value(&mut self, ty: Ty) -> std::result::Result<f64, String> {
        if self.format == Format::Ascii {
            let tok = self.tokens.next().ok_or("the file is truncated (too few values)")?;
            return tok.parse::<f64>().map_err(|_| format!("`{}` is not a number", tok.escape_debug()));
        }
        let n = ty.size();
        let b = self
            .bytes
            .get(self.pos..self.pos + n)
            .ok_or_else(|| format!("the file is truncated ({} data bytes, needed more)", self.bytes.len()))?;
        self.pos += n;
        let mut a = [0u8; 8];
        a[..n].copy_from_slice(b);
        if self.format == Format::BigEndian {
            a[..n].reverse();
        }
        let s2 = [a[0], a[1]];
        let s4 = [a[0], a[1], a[2], a[3]];
        Ok(match ty {
            Ty::I8 => a[0] as i8 as f64,
            Ty::U8 => a[0] as f64,
            Ty::I16 => i16::from_le_bytes(s2) as f64,
            Ty::U16 => u16::from_le_bytes(s2) as f64,
            Ty::I32 => i32::from_le_bytes(s4) as f64,
            Ty::U32 => u32::from_le_bytes(s4) as f64,
            Ty::F32 => f32::from_le_bytes(s4) as f64,
            Ty::F64 => f64::from_le_bytes(a),
        })
    }

    /// Reads a list length prefix.
    fn list_len(&mut self, ty: Ty) -> std::result::Result<usize, String> {
        let n = self.value(ty)?;
        if !(n >= 0.0 && n.fract() == 0.0 && n < 1e9) {
            return Err(format!("bad list length {n}"));
        }
        Ok(n as usize)
    }
}

/// Reads one row of `e`, storing each scalar property's value (lists are skipped, their slot is 0).
fn read_row(body: &mut Body, e: &Element, values: &mut [f64]) -> std::result::Result<(), String> {
    for (p, v) in e.props.iter().zip(values.iter_mut()) {
        *v = match p.list_count {
            None => body.value(p.ty)?,
            Some(count_ty) => {
                for _ in 0..body.list_len(count_ty)? {
                    body.value(p.ty)?;
                }
                0.0
            }
        };
    }
    Ok(())
}

fn skip_row(body: &mut Body, e: &Element) -> std::result::Result<(), String> {
    let mut values = vec![0.0; e.props.len()];
    read_row(body, e, &mut values)
}
