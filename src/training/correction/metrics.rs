//! Keep-mask metrics over the pixels that have input depth: 2-class mIoU, pixel accuracy, wrong depths
//! kept (FP) per map, and the official depth-weighted SAE.

use serde::Serialize;

/// Pixel counts by (label, prediction), over pixels with input depth, summed over maps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Confusion {
    /// Label keep, predicted keep.
    pub keep_keep: u64,
    /// Label keep, predicted drop (a good depth lost).
    pub keep_drop: u64,
    /// Label drop, predicted keep (a wrong depth kept: FP).
    pub drop_keep: u64,
    /// Label drop, predicted drop.
    pub drop_drop: u64,
    /// Maps added.
    pub maps: u64,
    /// Σ |I_s·[pred keep] − I_d·[label keep]| in metres over all pixels (the official SAE, per map summed).
    pub sae_m: f64,
}

/// The summary numbers of a [`Confusion`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct MaskMetrics {
    /// Mean of the keep-class and drop-class IoU, in [0, 1].
    pub miou: f64,
    pub iou_keep: f64,
    pub iou_drop: f64,
    /// Fraction of pixels with input depth labelled correctly.
    pub accuracy: f64,
    /// Wrong depths kept per map.
    pub fp_per_map: f64,
    /// Good depths dropped per map.
    pub fn_per_map: f64,
    /// Official SAE per map, metres.
    pub sae_per_map: f64,
    pub maps: u64,
    pub pixels: u64,
}

impl Confusion {
    /// Adds one map: `sparse` and `dense` depths (metres, 0 = missing; pixels "with input depth" are those
    /// where `has_depth`), the label and the predicted keep mask.
    pub fn add(
        &mut self,
        has_depth: impl Fn(usize) -> bool,
        sparse: &[f32],
        dense: &[f32],
        label_keep: &[bool],
        pred_keep: &[bool],
    ) {
        self.maps += 1;
        let mut sae = 0f64;
        for i in 0..label_keep.len() {
            if has_depth(i) {
                match (label_keep[i], pred_keep[i]) {
                    (true, true) => self.keep_keep += 1,
                    (true, false) => self.keep_drop += 1,
                    (false, true) => self.drop_keep += 1,
                    (false, false) => self.drop_drop += 1,
                }
            }
            let kept = if pred_keep[i] && has_depth(i) { sparse[i] } else { 0.0 };
            let reference = if label_keep[i] { dense[i] } else { 0.0 };
            sae += (kept - reference).abs() as f64;
        }
        self.sae_m += sae;
    }

    pub fn metrics(&self) -> MaskMetrics {
        let ratio = |a: u64, b: u64| if b == 0 { 1.0 } else { a as f64 / b as f64 };
        let iou_keep = ratio(self.keep_keep, self.keep_keep + self.keep_drop + self.drop_keep);
        let iou_drop = ratio(self.drop_drop, self.drop_drop + self.keep_drop + self.drop_keep);
        let pixels = self.keep_keep + self.keep_drop + self.drop_keep + self.drop_drop;
        let per_map = |v: f64| if self.maps == 0 { 0.0 } else { v / self.maps as f64 };
        MaskMetrics {
            miou: (iou_keep + iou_drop) / 2.0,
            iou_keep,
            iou_drop,
            accuracy: ratio(self.keep_keep + self.drop_drop, pixels),
            fp_per_map: per_map(self.drop_keep as f64),
            fn_per_map: per_map(self.keep_drop as f64),
            sae_per_map: per_map(self.sae_m),
            maps: self.maps,
            pixels,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_only_pixels_with_depth_and_computes_the_two_class_iou() {
        let sparse = [1.0f32, 2.0, 3.0, 4.0, 0.0];
        let dense = [1.0f32, 0.0, 2.0, 4.0, 5.0];
        let label = [true, false, false, true, false];
        let pred = [true, true, false, false, true];
        let mut c = Confusion::default();
        c.add(|i| sparse[i] > 0.0, &sparse, &dense, &label, &pred);
        assert_eq!((c.keep_keep, c.keep_drop, c.drop_keep, c.drop_drop), (1, 1, 1, 1));
        let m = c.metrics();
        assert!((m.miou - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!((m.accuracy, m.fp_per_map, m.pixels), (0.5, 1.0, 4));
        // SAE: |1-1| + |2-0| + 0 + |0-4| + |0-0| = 6.
        assert_eq!(c.sae_m, 6.0);
    }
}
