//! PLY point clouds: writing binary little-endian `x y z` floats, reading the vertex positions of
//! ascii or binary PLY files whatever other elements and properties they carry.

use crate::error::{Error, Result};
use crate::geometry::Point;
use std::path::Path;

/// A binary little-endian PLY of `points` (`element vertex N`, `property float x/y/z`).
pub fn encode_ply(points: &[Point]) -> Vec<u8> {
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by pointreggpt\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\nend_header\n",
        points.len()
    );
    let mut out = Vec::with_capacity(header.len() + 12 * points.len());
    out.extend_from_slice(header.as_bytes());
    for p in points {
        for v in [p.x, p.y, p.z] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// Writes [`encode_ply`] of `points` to `path`, creating parent folders.
pub fn write_ply(path: &Path, points: &[Point]) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    std::fs::write(path, encode_ply(points)).map_err(|e| Error::io(path, e))
}

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

#[cfg(test)]
mod tests {
    use super::*;

    fn pts() -> Vec<Point> {
        vec![Point::new(0.0, -1.5, 2.25), Point::new(1e-3, 3.0e4, -0.125), Point::new(-7.0, 0.5, 1.0)]
    }

    #[test]
    fn round_trip_and_exact_layout() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/cloud.ply");
        write_ply(&path, &pts()).unwrap();
        assert_eq!(read_ply(&path).unwrap(), pts());

        let bytes = std::fs::read(&path).unwrap();
        let header = "ply\nformat binary_little_endian 1.0\ncomment written by pointreggpt\nelement vertex 3\n\
                      property float x\nproperty float y\nproperty float z\nend_header\n";
        assert!(bytes.starts_with(header.as_bytes()));
        assert_eq!(bytes.len(), header.len() + 3 * 12);
        // Second point's y = 30000.0 = 0x46EA6000 as an IEEE single, little-endian.
        let at = header.len() + 12 + 4;
        assert_eq!(&bytes[at..at + 4], &[0x00, 0x60, 0xEA, 0x46]);
        assert_eq!(read_ply(&{
            let p = dir.path().join("empty.ply");
            write_ply(&p, &[]).unwrap();
            p
        })
        .unwrap(), vec![]);
    }

    #[test]
    fn ascii_with_normals_colours_and_faces() {
        let text = "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nobj_info test\r\nelement vertex 3\r\n\
                    property float nx\r\nproperty double x\r\nproperty double y\r\nproperty uchar red\r\n\
                    property double z\r\nproperty list uchar int tags\r\nelement face 1\r\n\
                    property list uchar int vertex_indices\r\nend_header\r\n\
                    0 1.5 2 255 -3 2 7 8\r\n1 0.25 -0.5 0 4e-1 0\r\n0 10 20 128 30 1 5\r\n3 0 1 2\r\n";
        let p = decode_ply(text.as_bytes(), Path::new("hand.ply")).unwrap();
        assert_eq!(p, vec![Point::new(1.5, 2.0, -3.0), Point::new(0.25, -0.5, 0.4), Point::new(10.0, 20.0, 30.0)]);
    }

    #[test]
    fn binary_big_endian_doubles_after_another_element() {
        let mut b = b"ply\nformat binary_big_endian 1.0\nelement camera 1\nproperty list uchar float k\n\
                      element vertex 2\nproperty uchar red\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
            .to_vec();
        b.push(2); // camera row: a list of two floats
        b.extend_from_slice(&1.0f32.to_be_bytes());
        b.extend_from_slice(&2.0f32.to_be_bytes());
        for (red, xyz) in [(9u8, [0.1f64, 0.2, 0.3]), (10, [-4.0, 5.5, 6.0])] {
            b.push(red);
            for v in xyz {
                b.extend_from_slice(&v.to_be_bytes());
            }
        }
        let p = decode_ply(&b, Path::new("be.ply")).unwrap();
        assert_eq!(p, vec![Point::new(0.1, 0.2, 0.3), Point::new(-4.0, 5.5, 6.0)]);
    }

    #[test]
    fn truncated_and_malformed_files_name_the_file() {
        let bytes = encode_ply(&pts());
        let e = decode_ply(&bytes[..bytes.len() - 5], Path::new("cut.ply")).unwrap_err().to_string();
        assert!(e.starts_with("cut.ply:") && e.contains("vertex 2 of 3") && e.contains("truncated"), "{e}");

        let ascii = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 5\n";
        let e = decode_ply(ascii.as_bytes(), Path::new("short.ply")).unwrap_err().to_string();
        assert!(e.contains("short.ply") && e.contains("vertex 1 of 2") && e.contains("truncated"), "{e}");

        let no_z = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n";
        let e = decode_ply(no_z.as_bytes(), Path::new("noz.ply")).unwrap_err().to_string();
        assert!(e.contains("noz.ply") && e.contains("no scalar `z`"), "{e}");

        let e = decode_ply(&bytes[..30], Path::new("head.ply")).unwrap_err().to_string();
        assert!(e.contains("head.ply") && e.contains("end_header"), "{e}");
        let e = decode_ply(b"PNG\n", Path::new("x.ply")).unwrap_err().to_string();
        assert!(e.contains("not a PLY file"), "{e}");
        let e = read_ply(Path::new("/nonexistent/dir/missing.ply")).unwrap_err().to_string();
        assert!(e.contains("missing.ply"), "{e}");
    }
}
