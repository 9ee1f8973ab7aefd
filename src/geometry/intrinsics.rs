//! Pinhole intrinsics and the resize-and-crop maps applied to depth maps and intrinsics together.

use crate::error::{Error, Result};
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

/// Pinhole intrinsics of an image `width`×`height` pixels (focal lengths and principal point in pixels).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// Checked constructor: focal lengths positive and finite, principal point finite, size non-zero.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64, width: u32, height: u32) -> Result<Self> {
        let k = Intrinsics { fx, fy, cx, cy, width, height };
        k.validate()?;
        Ok(k)
    }

    /// Checks the invariants of [`Intrinsics::new`] (for values that came through serde).
    pub fn validate(&self) -> Result<()> {
        if !(self.fx.is_finite() && self.fy.is_finite() && self.fx > 0.0 && self.fy > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "focal lengths must be positive and finite, got fx={} fy={}",
                self.fx, self.fy
            )));
        }
        if !(self.cx.is_finite() && self.cy.is_finite()) {
            return Err(Error::InvalidArgument(format!(
                "principal point must be finite, got cx={} cy={}",
                self.cx, self.cy
            )));
        }
        if self.width == 0 || self.height == 0 || self.width > 16384 || self.height > 16384 {
            return Err(Error::InvalidArgument(format!(
                "image size must be 1..=16384 pixels a side, got {}x{}",
                self.width, self.height
            )));
        }
        Ok(())
    }

    /// From a 3×3 camera matrix `[[fx,0,cx],[0,fy,cy],[0,0,1]]`.
    pub fn from_matrix(k: &Matrix3<f64>, width: u32, height: u32) -> Result<Self> {
        Intrinsics::new(k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)], width, height)
    }

    /// The 3×3 camera matrix.
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// `[fx, fy, cx, cy]`, the conditioning vector of the diffusion model.
    pub fn as_vector(&self) -> [f64; 4] {
        [self.fx, self.fy, self.cx, self.cy]
    }

    /// Intrinsics of the image resized to `width`×`height` by exact pixel-centre scaling
    /// (`c' + ½ = (c + ½)·s`), the general map for any resize.
    pub fn scaled(&self, width: u32, height: u32) -> Result<Self> {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Intrinsics::new(
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
            width,
            height,
        )
    }

    /// Intrinsics of the window `width`×`height` whose top-left pixel is (`left`, `top`).
    pub fn cropped(&self, left: u32, top: u32, width: u32, height: u32) -> Result<Self> {
        if left + width > self.width || top + height > self.height {
            return Err(Error::InvalidArgument(format!(
                "crop {}x{} at ({left},{top}) exceeds the {}x{} image",
                width, height, self.width, self.height
            )));
        }
        Intrinsics::new(self.fx, self.fy, self.cx - left as f64, self.cy - top as f64, width, height)
    }
}

/// A nearest-neighbour resize to `resized_width`×`resized_height` followed by a crop window.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ResizeCrop {
    pub source_width: u32,
    pub source_height: u32,
    pub resized_width: u32,
    pub resized_height: u32,
    pub left: u32,
    pub top: u32,
    pub width: u32,
    pub height: u32,
}

impl ResizeCrop {
    /// The official pipeline: torchvision `Resize(size)` (shorter side to `size`, longer side floored)
    /// then `CenterCrop(size)` (offset `round_half_even((resized − size)/2)`). 640×480 at 256 gives
    /// 341×256 and columns 42..298.
    pub fn official(source_width: u32, source_height: u32, size: u32) -> Result<Self> {
        if source_width == 0 || source_height == 0 || size == 0 {
            return Err(Error::InvalidArgument("resize-crop sizes must be positive".into()));
        }
        let (rw, rh) = if source_width >= source_height {
            ((size as u64 * source_width as u64 / source_height as u64) as u32, size)
        } else {
            (size, (size as u64 * source_height as u64 / source_width as u64) as u32)
        };
        let left = ((rw - size) as f64 / 2.0).round_ties_even() as u32;
        let top = ((rh - size) as f64 / 2.0).round_ties_even() as u32;
        Ok(ResizeCrop {
            source_width,
            source_height,
            resized_width: rw,
            resized_height: rh,
            left,
            top,
            width: size,
            height: size,
        })
    }

    /// Source column of output column `c` (PIL's NEAREST: `floor((c_resized + ½)·W/W')`).
    pub fn source_column(&self, c: u32) -> u32 {
        nearest_source(c + self.left, self.source_width, self.resized_width)
    }

    /// Source row of output row `r`.
    pub fn source_row(&self, r: u32) -> u32 {
        nearest_source(r + self.top, self.source_height, self.resized_height)
    }

    /// The official intrinsics map (reference §3.1): focal lengths scaled by the resize, principal point
    /// *assumed* at the image centre: `cx' = W'/2 − left`, `cy' = H'/2 − top`.
    pub fn official_intrinsics(&self, k: &Intrinsics) -> Result<Intrinsics> {
        Intrinsics::new(
            k.fx * self.resized_width as f64 / self.source_width as f64,
            k.fy * self.resized_height as f64 / self.source_height as f64,
            self.resized_width as f64 / 2.0 - self.left as f64,
            self.resized_height as f64 / 2.0 - self.top as f64,
            self.width,
            self.height,
        )
    }

    /// The exact intrinsics map: pixel-centre scaling then the crop offset (honours an off-centre
    /// principal point).
    pub fn exact_intrinsics(&self, k: &Intrinsics) -> Result<Intrinsics> {
        k.scaled(self.resized_width, self.resized_height)?.cropped(self.left, self.top, self.width, self.height)
    }
}

fn nearest_source(i: u32, source: u32, resized: u32) -> u32 {
    let s = ((i as f64 + 0.5) * source as f64 / resized as f64).floor() as u32;
    s.min(source - 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn official_map_of_640x480_matches_the_reference() {
        let rc = ResizeCrop::official(640, 480, 256).unwrap();
        assert_eq!((rc.resized_width, rc.resized_height, rc.left, rc.top), (341, 256, 42, 0));
        let k = Intrinsics::new(585.0, 585.0, 320.0, 240.0, 640, 480).unwrap();
        let k2 = rc.official_intrinsics(&k).unwrap();
        assert!((k2.fx - 585.0 * 341.0 / 640.0).abs() < 1e-12);
        assert!((k2.fy - 312.0).abs() < 1e-12);
        assert_eq!((k2.cx, k2.cy, k2.width, k2.height), (128.5, 128.0, 256, 256));
        // Reference table: 585 -> 311.695 / 312.000
        assert!((k2.fx - 311.695).abs() < 1e-3);
    }

    #[test]
    fn nearest_source_follows_pil() {
        let rc = ResizeCrop::official(640, 480, 256).unwrap();
        // output column 0 is resized column 42: floor(42.5 * 640 / 341) = floor(79.765) = 79
        assert_eq!(rc.source_column(0), 79);
        // rows: floor((r + 0.5) * 480/256)
        assert_eq!(rc.source_row(0), 0);
        assert_eq!(rc.source_row(255), 479);
        assert_eq!(rc.source_row(1), 2);
    }

    #[test]
    fn exact_map_agrees_with_official_when_principal_point_is_centred_up_to_half_pixel_shift() {
        // With cx = (W-1)/2 (true pixel-centre centring) the exact map gives (W'-1)/2 - left.
        let rc = ResizeCrop::official(640, 480, 256).unwrap();
        let k = Intrinsics::new(500.0, 500.0, 319.5, 239.5, 640, 480).unwrap();
        let e = rc.exact_intrinsics(&k).unwrap();
        assert!((e.cx - (340.0 / 2.0 - 42.0)).abs() < 1e-9);
        assert!((e.cy - 127.5).abs() < 1e-9);
    }

    #[test]
    fn rejects_bad_values() {
        assert!(Intrinsics::new(0.0, 1.0, 0.0, 0.0, 10, 10).is_err());
        assert!(Intrinsics::new(f64::NAN, 1.0, 0.0, 0.0, 10, 10).is_err());
        assert!(Intrinsics::new(1.0, 1.0, 0.0, 0.0, 0, 10).is_err());
        let k = Intrinsics::new(1.0, 1.0, 0.0, 0.0, 10, 10).unwrap();
        assert!(k.cropped(5, 0, 6, 10).is_err());
    }
}
