//! 16-bit grayscale PNG depth images: decode, read, encode, write.

use crate::error::{Error, Result};
use std::path::Path;

/// Raw 16-bit depth samples of one image, row-major, in the file's units.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawDepth {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u16>,
}

/// Decodes a 16-bit single-channel PNG held in memory; `path` only names the file in errors.
pub fn decode_depth_png(bytes: &[u8], path: &Path) -> Result<RawDepth> {
    let bad = |m: String| Error::input(path, m);
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().map_err(|e| bad(format!("not a readable PNG ({e})")))?;
    let info = reader.info();
    let (width, height, color, depth) = (info.width, info.height, info.color_type, info.bit_depth);
    if color != png::ColorType::Grayscale || depth != png::BitDepth::Sixteen {
        return Err(bad(format!(
            "depth PNG must be 16-bit grayscale, found {color:?} with {} bits per sample",
            depth as u8
        )));
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| bad("PNG image is too large".into()))?;
    let mut buf = vec![0u8; size];
    let frame = reader
        .next_frame(&mut buf)
        .map_err(|e| bad(format!("PNG data is truncated or corrupt ({e})")))?;
    buf.truncate(frame.buffer_size());
    let data: Vec<u16> = buf.chunks_exact(2).map(|b| u16::from_be_bytes([b[0], b[1]])).collect();
    if data.len() != width as usize * height as usize {
        return Err(bad(format!("PNG holds {} samples, expected {}x{}", data.len(), width, height)));
    }
    Ok(RawDepth { width, height, data })
}

/// Reads a 16-bit depth PNG from disk.
pub fn read_depth_png(path: &Path) -> Result<RawDepth> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode_depth_png(&bytes, path)
}

/// Encodes `data` (row-major, `width`×`height`) as a 16-bit grayscale PNG.
pub fn encode_depth_png(width: u32, height: u32, data: &[u16]) -> Result<Vec<u8>> {
    if data.len() != width as usize * height as usize {
        return Err(Error::InvalidArgument(format!(
            "depth PNG {}x{} needs {} samples, got {}",
            width,
            height,
            width as usize * height as usize,
            data.len()
        )));
    }
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        enc.set_compression(png::Compression::Fast);
        let mut w = enc.write_header().map_err(|e| Error::Internal(format!("png header: {e}")))?;
        let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_be_bytes()).collect();
        w.write_image_data(&bytes).map_err(|e| Error::Internal(format!("png data: {e}")))?;
    }
    Ok(out)
}

/// Writes a 16-bit depth PNG, creating parent folders.
pub fn write_depth_png(path: &Path, width: u32, height: u32, data: &[u16]) -> Result<()> {
    let bytes = encode_depth_png(width, height, data)?;
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    std::fs::write(path, bytes).map_err(|e| Error::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_every_sample() {
        let data: Vec<u16> = (0..37 * 23).map(|i| (i * 977 % 65536) as u16).collect();
        let bytes = encode_depth_png(37, 23, &data).unwrap();
        let back = decode_depth_png(&bytes, Path::new("mem.png")).unwrap();
        assert_eq!(back, RawDepth { width: 37, height: 23, data });
    }

    #[test]
    fn truncated_and_8bit_files_name_the_file() {
        let bytes = encode_depth_png(16, 16, &[500; 256]).unwrap();
        let err = decode_depth_png(&bytes[..bytes.len() / 2], Path::new("cut.png")).unwrap_err().to_string();
        assert!(err.starts_with("cut.png:") && err.contains("truncated"), "{err}");

        let mut eight = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut eight, 4, 4);
            enc.set_color(png::ColorType::Grayscale);
            enc.set_depth(png::BitDepth::Eight);
            enc.write_header().unwrap().write_image_data(&[0; 16]).unwrap();
        }
        let err = decode_depth_png(&eight, Path::new("gray8.png")).unwrap_err().to_string();
        assert!(err.contains("gray8.png") && err.contains("16-bit"), "{err}");
        let err = decode_depth_png(b"hello", Path::new("text.png")).unwrap_err().to_string();
        assert!(err.contains("text.png") && err.contains("not a readable PNG"), "{err}");
    }
}
