//! NumPy `.npy` files (format version 1.0): point clouds (float32 (N, 3)), depth images (float32 (H, W))
//! and masks (bool (H, W)).

use crate::error::{Error, Result};
use crate::geometry::Point;
use std::path::Path;

/// The `.npy` bytes of `points` as a little-endian float32 (N, 3) C-ordered array (what
/// `np.save(path, np.asarray(points, np.float32))` writes).
pub fn encode_npy_points(points: &[Point]) -> Vec<u8> {
    let mut out = npy_header("<f4", &format!("({}, 3)", points.len()));
    for p in points {
        for v in [p.x, p.y, p.z] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// The `.npy` bytes of a row-major `height`×`width` float32 image (`np.save` of a (H, W) `<f4` array).
pub fn encode_npy_image_f32(width: usize, height: usize, data: &[f32]) -> Vec<u8> {
    assert_eq!(data.len(), width * height, "image size");
    let mut out = npy_header("<f4", &format!("({height}, {width})"));
    data.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
    out
}

/// The `.npy` bytes of a row-major `height`×`width` boolean mask (`np.save` of a (H, W) `bool` array).
pub fn encode_npy_mask(width: usize, height: usize, mask: &[bool]) -> Vec<u8> {
    assert_eq!(mask.len(), width * height, "mask size");
    let mut out = npy_header("|b1", &format!("({height}, {width})"));
    out.extend(mask.iter().map(|b| *b as u8));
    out
}

/// The `.npy` bytes of a float32 vector (N,) (`np.save` of a `<f4` array).
pub fn encode_npy_vector_f32(values: &[f32]) -> Vec<u8> {
    let mut out = npy_header("<f4", &format!("({},)", values.len()));
    values.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
    out
}

/// The `.npy` bytes of an int8 vector (N,) (`np.save` of an `|i1` array).
pub fn encode_npy_vector_i8(values: &[i8]) -> Vec<u8> {
    let mut out = npy_header("|i1", &format!("({},)", values.len()));
    out.extend(values.iter().map(|v| *v as u8));
    out
}

/// Magic, version 1.0, header length and the header dict padded with spaces and a newline so the data
/// starts at a multiple of 64 bytes.
fn npy_header(descr: &str, shape: &str) -> Vec<u8> {
    let dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    // magic (6) + version (2) + header length (2) + dict + padding + '\n', a multiple of 64.
    let unpadded = 10 + dict.len() + 1;
    let header_len = dict.len() + 1 + (64 - unpadded % 64) % 64;
    let mut out = Vec::with_capacity(10 + header_len);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header_len as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out.resize(10 + header_len - 1, b' ');
    out.push(b'\n');
    out
}

/// Writes [`encode_npy_points`] to `path`, creating parent folders.
pub fn write_npy_points(path: &Path, points: &[Point]) -> Result<()> {
    write_npy(path, &encode_npy_points(points))
}

/// Writes `.npy` bytes to `path`, creating parent folders.
pub fn write_npy(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    std::fs::write(path, bytes).map_err(|e| Error::io(path, e))
}

/// Reads back a file written by [`write_npy_points`] (only that exact layout: `<f4`, C order, (N, 3)).
pub fn read_npy_points(path: &Path) -> Result<Vec<Point>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let bad = |m: &str| Error::input(path, m.to_string());
    if bytes.len() < 10 || &bytes[..8] != b"\x93NUMPY\x01\x00" {
        return Err(bad("not a version 1.0 .npy file"));
    }
    let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(bytes.get(10..10 + header_len).ok_or_else(|| bad("truncated header"))?).map_err(|_| bad("header is not text"))?;
    if !header.contains("'descr': '<f4'") || !header.contains("'fortran_order': False") {
        return Err(bad("expected a little-endian float32 C-ordered array"));
    }
    let shape = header.split("'shape': (").nth(1).and_then(|s| s.split(')').next()).ok_or_else(|| bad("no shape"))?;
    let dims: Vec<usize> = shape.split(',').map(str::trim).filter(|s| !s.is_empty()).map(|s| s.parse()).collect::<std::result::Result<_, _>>().map_err(|_| bad("bad shape"))?;
    if dims.len() != 2 || dims[1] != 3 {
        return Err(bad("expected shape (N, 3)"));
    }
    let data = &bytes[10 + header_len..];
    if data.len() != dims[0] * 12 {
        return Err(bad("data size does not match the shape"));
    }
    let f = |c: &[u8]| f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
    Ok(data.chunks_exact(12).map(|c| Point::new(f(&c[0..4]), f(&c[4..8]), f(&c[8..12]))).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_is_64_aligned_like_numpy_and_round_trips() {
        let pts = vec![Point::new(1.0, -2.0, 3.5), Point::new(0.25, 0.0, 1e-3)];
        let b = encode_npy_points(&pts);
        let header_len = u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!((10 + header_len) % 64, 0);
        assert_eq!(b[10 + header_len - 1], b'\n');
        // numpy 2.2: np.save of a (5, 3) float32 array has this exact header.
        let five = encode_npy_points(&[Point::origin(); 5]);
        let dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': (5, 3), }}{}\n", " ".repeat(58));
        let want = [&b"\x93NUMPY\x01\x00v\x00"[..], dict.as_bytes()].concat();
        assert_eq!(&five[..128], &want[..]);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a/b.npy");
        write_npy_points(&p, &pts).unwrap();
        assert_eq!(read_npy_points(&p).unwrap(), pts);
    }

    #[test]
    fn images_and_masks_are_what_numpy_saves() {
        // The bytes numpy 2.2 writes for np.save(np.arange(6, dtype=np.float32).reshape(2, 3) * 0.5) and
        // for np.save(np.array([[True, False, True], [False, False, True]])).
        let pad = |dict: &str| format!("{dict}{}\n", " ".repeat(128 - 10 - dict.len() - 1));
        let image = encode_npy_image_f32(3, 2, &[0.0, 0.5, 1.0, 1.5, 2.0, 2.5]);
        let dict = pad("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }");
        let mut want = [&b"\x93NUMPY\x01\x00v\x00"[..], dict.as_bytes()].concat();
        [0.0f32, 0.5, 1.0, 1.5, 2.0, 2.5].iter().for_each(|v| want.extend_from_slice(&v.to_le_bytes()));
        assert_eq!(image, want);
        let mask = encode_npy_mask(3, 2, &[true, false, true, false, false, true]);
        let dict = pad("{'descr': '|b1', 'fortran_order': False, 'shape': (2, 3), }");
        let want = [&b"\x93NUMPY\x01\x00v\x00"[..], dict.as_bytes(), &[1, 0, 1, 0, 0, 1]].concat();
        assert_eq!(mask, want);
    }
}
