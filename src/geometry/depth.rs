//! Depth maps in metres and their back-projection to points.

use super::{Intrinsics, Point, ResizeCrop};
use crate::error::{Error, Result};
use rayon::prelude::*;

/// A depth map in metres, row-major; 0 marks a pixel without depth.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthMap {
    width: u32,
    height: u32,
    data: Vec<f32>,
}

impl DepthMap {
    /// A map from row-major metres; every value must be finite and non-negative.
    pub fn new(width: u32, height: u32, data: Vec<f32>) -> Result<Self> {
        if data.len() != width as usize * height as usize {
            return Err(Error::InvalidArgument(format!(
                "depth map {}x{} needs {} values, got {}",
                width,
                height,
                width as usize * height as usize,
                data.len()
            )));
        }
        if let Some(v) = data.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            return Err(Error::InvalidArgument(format!("depth values must be finite and >= 0, found {v}")));
        }
        Ok(DepthMap { width, height, data })
    }

    /// A map whose values the caller already knows are finite and non-negative (projection output).
    pub(crate) fn from_checked_parts(width: u32, height: u32, data: Vec<f32>) -> Self {
        debug_assert!(
            data.len() == width as usize * height as usize && data.iter().all(|v| v.is_finite() && *v >= 0.0)
        );
        DepthMap { width, height, data }
    }

    /// An all-invalid map.
    pub fn zeros(width: u32, height: u32) -> Self {
        DepthMap { width, height, data: vec![0.0; width as usize * height as usize] }
    }

    /// From raw sensor units (for example millimetres with `scale = 1000`); the values in `invalid`
    /// (typically 0 and 65535) become 0.
    pub fn from_raw(width: u32, height: u32, raw: &[u16], scale: f32, invalid: &[u16]) -> Result<Self> {
        if raw.len() != width as usize * height as usize {
            return Err(Error::InvalidArgument("raw depth size does not match width x height".into()));
        }
        let data = raw.iter().map(|&v| if invalid.contains(&v) { 0.0 } else { v as f32 / scale }).collect();
        Ok(DepthMap { width, height, data })
    }

    /// To raw units (`round(z·scale)`); values that do not fit below 65535 become 0 (invalid).
    pub fn to_raw(&self, scale: f32) -> Vec<u16> {
        self.data
            .iter()
            .map(|&z| {
                let v = (z * scale).round();
                if v >= 1.0 && v < 65535.0 {
                    v as u16
                } else {
                    0
                }
            })
            .collect()
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    /// Row-major metres.
    pub fn data(&self) -> &[f32] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }
    pub fn into_data(self) -> Vec<f32> {
        self.data
    }
    /// Depth at column `c`, row `r`.
    pub fn at(&self, c: u32, r: u32) -> f32 {
        self.data[r as usize * self.width as usize + c as usize]
    }
    /// Number of pixels with depth.
    pub fn valid_count(&self) -> usize {
        self.data.iter().filter(|z| **z > 0.0).count()
    }

    /// Sets every depth outside `(near, far)` to 0.
    pub fn clip(&mut self, range: DepthRange) {
        for z in &mut self.data {
            if !range.contains(*z) {
                *z = 0.0;
            }
        }
    }

    /// Applies `rc` (nearest resize, then crop) — the image side of [`ResizeCrop`].
    pub fn resize_crop(&self, rc: &ResizeCrop) -> Result<Self> {
        if rc.source_width != self.width || rc.source_height != self.height {
            return Err(Error::InvalidArgument(format!(
                "resize-crop expects a {}x{} map, got {}x{}",
                rc.source_width, rc.source_height, self.width, self.height
            )));
        }
        let cols: Vec<usize> = (0..rc.width).map(|c| rc.source_column(c) as usize).collect();
        let mut data = Vec::with_capacity(rc.width as usize * rc.height as usize);
        for r in 0..rc.height {
            let row = rc.source_row(r) as usize * self.width as usize;
            data.extend(cols.iter().map(|&c| self.data[row + c]));
        }
        Ok(DepthMap { width: rc.width, height: rc.height, data })
    }
}

/// The open interval of depths kept when back-projecting (`near < z < far`, metres), as the
/// official `clip` does.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DepthRange {
    pub near: f32,
    pub far: f32,
}

impl DepthRange {
    /// The official generation range, 0.5–10 m.
    pub const OFFICIAL: DepthRange = DepthRange { near: 0.5, far: 10.0 };
    /// Everything with depth.
    pub const ANY: DepthRange = DepthRange { near: 0.0, far: f32::INFINITY };

    pub fn contains(&self, z: f32) -> bool {
        z > self.near && z < self.far
    }
}

/// Points of the pixels of `depth` whose depth lies in `range`, in the camera frame, in row-major
/// pixel order: `x = (c − cx)·z/fx`, `y = (r − cy)·z/fy`.
pub fn backproject(depth: &DepthMap, k: &Intrinsics, range: DepthRange) -> Vec<Point> {
    backproject_rows(depth, k, range, false).0
}

/// As [`backproject`], also returning each point's pixel index `r·W + c`.
pub fn backproject_with_pixels(depth: &DepthMap, k: &Intrinsics, range: DepthRange) -> (Vec<Point>, Vec<u32>) {
    backproject_rows(depth, k, range, true)
}

/// Both back-projections: blocks of rows are counted, then each block writes its points (and pixel
/// indices, when asked) straight into its part of the output, in parallel.
fn backproject_rows(depth: &DepthMap, k: &Intrinsics, range: DepthRange, with_pixels: bool) -> (Vec<Point>, Vec<u32>) {
    use std::mem::MaybeUninit;
    assert_eq!((depth.width, depth.height), (k.width, k.height), "depth map and intrinsics sizes differ");
    let w = depth.width as usize;
    let ax: Vec<f32> = (0..w).map(|c| ((c as f64 - k.cx) / k.fx) as f32).collect();
    const ROWS: usize = 16;
    let block = (w * ROWS).max(1);
    let counts: Vec<usize> =
        depth.data.par_chunks(block).map(|b| b.iter().map(|&z| range.contains(z) as usize).sum()).collect();
    let n: usize = counts.iter().sum();
    let mut points: Vec<Point> = Vec::with_capacity(n);
    let mut pixels: Vec<u32> = Vec::with_capacity(if with_pixels { n } else { 0 });
    // Each block's slice of the (uninitialised) outputs.
    fn split<'a, T>(mut rest: &'a mut [MaybeUninit<T>], counts: &[usize]) -> Vec<&'a mut [MaybeUninit<T>]> {
        counts
            .iter()
            .map(|&c| {
                let (head, tail) = std::mem::take(&mut rest).split_at_mut(c);
                rest = tail;
                head
            })
            .collect()
    }
    let point_parts = split(&mut points.spare_capacity_mut()[..n], &counts);
    let pixel_parts = match with_pixels {
        true => split(&mut pixels.spare_capacity_mut()[..n], &counts),
        false => counts.iter().map(|_| <&mut [MaybeUninit<u32>]>::default()).collect(),
    };
    depth.data.par_chunks(block).zip(point_parts).zip(pixel_parts).enumerate().for_each(|(b, ((data, pts), pix))| {
        let mut j = 0;
        for (rr, row) in data.chunks(w).enumerate() {
            let r = b * ROWS + rr;
            let ay = ((r as f64 - k.cy) / k.fy) as f32;
            for (c, &z) in row.iter().enumerate() {
                if range.contains(z) {
                    pts[j].write(Point::new(ax[c] * z, ay * z, z));
                    if with_pixels {
                        pix[j].write((r * w + c) as u32);
                    }
                    j += 1;
                }
            }
        }
        assert_eq!(j, pts.len(), "a block wrote as many points as it counted");
    });
    // SAFETY: every block wrote exactly its count of elements (asserted above), and the blocks' slices
    // tile the first `n` elements of each output.
    unsafe {
        points.set_len(n);
        if with_pixels {
            pixels.set_len(n);
        }
    }
    (points, pixels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_backprojects_to_the_analytic_points() {
        let k = Intrinsics::new(100.0, 120.0, 15.5, 10.0, 32, 24).unwrap();
        let d = DepthMap::new(32, 24, vec![2.0; 32 * 24]).unwrap();
        let (pts, pix) = backproject_with_pixels(&d, &k, DepthRange::ANY);
        assert_eq!(pts.len(), 32 * 24);
        for (p, &i) in pts.iter().zip(&pix) {
            let (c, r) = ((i % 32) as f32, (i / 32) as f32);
            assert!((p.x - (c - 15.5) * 2.0 / 100.0).abs() < 1e-6);
            assert!((p.y - (r - 10.0) * 2.0 / 120.0).abs() < 1e-6);
            assert_eq!(p.z, 2.0);
        }
    }

    #[test]
    fn holes_and_range_agree_with_a_pixel_loop_on_any_thread_count() {
        // 37 rows: blocks of rows end mid-map; a third of the pixels are holes or out of range.
        let (w, h) = (53u32, 37u32);
        let k = Intrinsics::new(60.0, 61.0, 26.0, 18.5, w, h).unwrap();
        let mut r = crate::rng::Rng::new(4);
        let data: Vec<f32> = (0..w * h)
            .map(|_| match r.next_u64() % 6 {
                0 => 0.0,
                1 => 12.0,
                _ => r.uniform_range(0.3, 4.0) as f32,
            })
            .collect();
        let d = DepthMap::new(w, h, data).unwrap();
        let range = DepthRange::OFFICIAL;
        let (mut pts, mut pix) = (Vec::new(), Vec::new());
        for row in 0..h as usize {
            for c in 0..w as usize {
                let z = d.data()[row * w as usize + c];
                if range.contains(z) {
                    let ax = ((c as f64 - k.cx) / k.fx) as f32;
                    let ay = ((row as f64 - k.cy) / k.fy) as f32;
                    pts.push(Point::new(ax * z, ay * z, z));
                    pix.push((row * w as usize + c) as u32);
                }
            }
        }
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            assert_eq!(pool.install(|| backproject(&d, &k, range)), pts);
            assert_eq!(pool.install(|| backproject_with_pixels(&d, &k, range)), (pts.clone(), pix.clone()));
        }
    }

    #[test]
    fn clip_range_is_open() {
        let k = Intrinsics::new(10.0, 10.0, 1.0, 0.0, 3, 1).unwrap();
        let d = DepthMap::new(3, 1, vec![0.5, 0.75, 10.0]).unwrap();
        let pts = backproject(&d, &k, DepthRange::OFFICIAL);
        assert_eq!(pts.len(), 1);
        assert_eq!(pts[0].z, 0.75);
    }

    #[test]
    fn raw_round_trip_and_invalid_codes() {
        let d = DepthMap::from_raw(4, 1, &[0, 1234, 65535, 7], 1000.0, &[0, 65535]).unwrap();
        assert_eq!(d.data(), &[0.0, 1.234, 0.0, 0.007]);
        assert_eq!(d.to_raw(1000.0), vec![0, 1234, 0, 7]);
        let far = DepthMap::new(1, 1, vec![70.0]).unwrap();
        assert_eq!(far.to_raw(1000.0), vec![0]);
    }

    #[test]
    fn resize_crop_picks_pil_nearest_pixels() {
        let rc = ResizeCrop::official(640, 480, 256).unwrap();
        let data: Vec<f32> = (0..640 * 480).map(|i| i as f32).collect();
        let d = DepthMap::new(640, 480, data).unwrap();
        let out = d.resize_crop(&rc).unwrap();
        assert_eq!((out.width(), out.height()), (256, 256));
        for (c, r) in [(0u32, 0u32), (255, 255), (100, 37)] {
            let sc = (((c + 42) as f64 + 0.5) * 640.0 / 341.0).floor() as u32;
            let sr = ((r as f64 + 0.5) * 480.0 / 256.0).floor() as u32;
            assert_eq!(out.at(c, r), (sr * 640 + sc) as f32);
        }
    }

    #[test]
    fn rejects_nan_and_wrong_sizes() {
        assert!(DepthMap::new(2, 1, vec![1.0]).is_err());
        assert!(DepthMap::new(1, 1, vec![f32::NAN]).is_err());
        assert!(DepthMap::new(1, 1, vec![-1.0]).is_err());
    }
}
