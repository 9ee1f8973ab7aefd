//! An RGB8 raster with clipped rectangles, bitmap text and PNG output: the whole drawing toolkit of
//! the preview montages and the stats plot.

use super::font::{glyph, CELL_W, GLYPH_H, GLYPH_W};
use crate::error::{Error, Result};
use std::path::Path;

/// An RGB colour.
pub type Rgb = [u8; 3];

/// A row-major RGB8 image.
#[derive(Clone, Debug, PartialEq)]
pub struct Canvas {
    pub width: u32,
    pub height: u32,
    /// `width × height × 3` bytes.
    pub data: Vec<u8>,
}

impl Canvas {
    /// A canvas filled with `background`.
    pub fn new(width: u32, height: u32, background: Rgb) -> Self {
        let data = background.iter().copied().cycle().take(width as usize * height as usize * 3).collect();
        Canvas { width, height, data }
    }

    /// The colour at (x, y); panics outside the canvas.
    pub fn get(&self, x: u32, y: u32) -> Rgb {
        let i = (y as usize * self.width as usize + x as usize) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Sets (x, y) when it lies on the canvas.
    pub fn set(&mut self, x: i64, y: i64, c: Rgb) {
        if x >= 0 && y >= 0 && x < self.width as i64 && y < self.height as i64 {
            let i = (y as usize * self.width as usize + x as usize) * 3;
            self.data[i..i + 3].copy_from_slice(&c);
        }
    }

    /// Fills the rectangle at (x, y) of size w × h, clipped to the canvas.
    pub fn fill_rect(&mut self, x: i64, y: i64, w: i64, h: i64, c: Rgb) {
        let (x0, y0) = (x.max(0), y.max(0));
        let (x1, y1) = ((x + w).min(self.width as i64), (y + h).min(self.height as i64));
        for yy in y0..y1 {
            for xx in x0..x1 {
                self.set(xx, yy, c);
            }
        }
    }

    /// A one-pixel rectangle outline.
    pub fn outline(&mut self, x: i64, y: i64, w: i64, h: i64, c: Rgb) {
        self.fill_rect(x, y, w, 1, c);
        self.fill_rect(x, y + h - 1, w, 1, c);
        self.fill_rect(x, y, 1, h, c);
        self.fill_rect(x + w - 1, y, 1, h, c);
    }

    /// Copies `other` with its top-left corner at (x, y), clipped.
    pub fn blit(&mut self, x: i64, y: i64, other: &Canvas) {
        for r in 0..other.height {
            for c in 0..other.width {
                self.set(x + c as i64, y + r as i64, other.get(c, r));
            }
        }
    }

    /// Draws `text` with its top-left at (x, y), each font pixel `scale`×`scale`; returns the width.
    pub fn text(&mut self, x: i64, y: i64, text: &str, c: Rgb, scale: u32) -> i64 {
        let s = scale.max(1) as i64;
        for (i, ch) in text.chars().enumerate() {
            let ox = x + i as i64 * CELL_W as i64 * s;
            for (r, bits) in glyph(ch).iter().enumerate() {
                for col in 0..GLYPH_W {
                    if bits >> (GLYPH_W - 1 - col) & 1 == 1 {
                        self.fill_rect(ox + col as i64 * s, y + r as i64 * s, s, s, c);
                    }
                }
            }
        }
        text_width(text, scale)
    }

    /// Draws `text` centred horizontally on `cx`.
    pub fn text_centered(&mut self, cx: i64, y: i64, text: &str, c: Rgb, scale: u32) {
        self.text(cx - text_width(text, scale) / 2, y, text, c, scale);
    }

    /// The PNG (8-bit RGB) bytes of the canvas.
    pub fn encode_png(&self) -> Result<Vec<u8>> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.write_header()
                .and_then(|mut w| w.write_image_data(&self.data))
                .map_err(|e| Error::Internal(format!("cannot encode PNG: {e}")))?;
        }
        Ok(out)
    }

    /// Writes [`Canvas::encode_png`] to `path`.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        std::fs::write(path, self.encode_png()?).map_err(|e| Error::io(path, e))
    }
}

/// Width in pixels of `text` drawn at `scale` (without the trailing gap).
pub fn text_width(text: &str, scale: u32) -> i64 {
    let n = text.chars().count() as i64;
    if n == 0 {
        0
    } else {
        (n * CELL_W as i64 - (CELL_W - GLYPH_W) as i64) * scale.max(1) as i64
    }
}

/// Height in pixels of one line of text at `scale`.
pub fn text_height(scale: u32) -> i64 {
    GLYPH_H as i64 * scale.max(1) as i64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_clipped_shapes_and_text_and_encodes() {
        let mut c = Canvas::new(20, 10, [1, 2, 3]);
        c.fill_rect(-5, -5, 8, 8, [255, 0, 0]);
        assert_eq!(c.get(2, 2), [255, 0, 0]);
        assert_eq!(c.get(3, 3), [1, 2, 3]);
        c.fill_rect(18, 8, 10, 10, [0, 255, 0]);
        assert_eq!(c.get(19, 9), [0, 255, 0]);
        let w = c.text(0, 0, "I", [9, 9, 9], 1);
        assert_eq!(w, 5);
        assert_eq!(c.get(2, 1), [9, 9, 9]); // the stem of I
        assert_eq!(text_width("AB", 2), 22);
        let png = c.encode_png().unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(png)).read_info().unwrap();
        assert_eq!((dec.info().width, dec.info().height), (20, 10));
    }
}
