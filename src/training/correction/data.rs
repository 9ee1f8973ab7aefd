//! Label shards as in-memory training examples: the sparse re-projection `I_s` (network input), the
//! dense `I_d` and the keep label `M_gt`.

use crate::nn::space::normalise_depth;
use crate::error::{Error, Result};
use crate::shards::dataset::Dataset;
use crate::shards::labels::{batch_to_labels, LABELS_TABLE};
use crate::shards::row::Status;
use crate::sources::depth_png::decode_depth_png;
use std::path::Path;

/// One example: depths in metres (0 = missing) and the label (`true` = keep).
#[derive(Clone, Debug)]
pub struct LabelExample {
    pub key: String,
    pub scene: String,
    /// Index of the fused window the example came from.
    pub unit_index: u64,
    pub sparse: Vec<f32>,
    pub dense: Vec<f32>,
    pub keep: Vec<bool>,
    /// Where the example was seen from: the keys of its window's first, last and reference frames, the
    /// target camera's working intrinsics `[fx, fy, cx, cy]` and `T_target_from_reference` (row-major).
    pub window: LabelWindow,
}

/// The frames and camera of a label example (for a scene around its window, `eval correction --scene`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LabelWindow {
    pub first_frame: String,
    pub last_frame: String,
    pub reference_frame: String,
    pub intrinsics: [f64; 4],
    pub t_target_from_reference: [f64; 16],
}

impl LabelExample {
    /// The network input: `I_s / 10 m`, values beyond 10 m as missing.
    pub fn input(&self) -> Vec<f32> {
        self.sparse.iter().map(|z| normalise_depth(*z)).collect()
    }

    /// Whether a pixel has input depth (the pixels a corrector can keep or drop).
    pub fn has_depth(&self, i: usize) -> bool {
        normalise_depth(self.sparse[i]) > 0.0
    }
}

/// Every `ok` example of one or more label datasets, all of one size.
#[derive(Clone, Debug, Default)]
pub struct LabelSet {
    pub width: usize,
    pub height: usize,
    pub examples: Vec<LabelExample>,
}

/// Decodes an 8-bit grayscale mask PNG (> 127 = `true`).
pub fn decode_mask_png(bytes: &[u8], name: &str) -> Result<Vec<bool>> {
    let bad = |m: String| Error::input(name, m);
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .map_err(|e| bad(format!("label PNG is not readable ({e})")))?;
    let (color, depth) = (reader.info().color_type, reader.info().bit_depth);
    if color != png::ColorType::Grayscale || depth != png::BitDepth::Eight {
        return Err(bad(format!("label PNG must be 8-bit grayscale, found {color:?} {depth:?}")));
    }
    let mut buf = vec![0u8; reader.output_buffer_size().ok_or_else(|| bad("label PNG too large".into()))?];
    let info = reader.next_frame(&mut buf).map_err(|e| bad(format!("label PNG is corrupt ({e})")))?;
    Ok(buf[..info.buffer_size()].iter().map(|v| *v > 127).collect())
}

impl LabelSet {
    /// Reads every committed `labels` shard of the dataset at `root` (rows with status `ok`), ordered by
    /// (window, sample).
    pub fn open(root: &Path) -> Result<LabelSet> {
        let ds = Dataset::open(root)?;
        let mut rows = Vec::new();
        for entry in ds.committed(LABELS_TABLE)?.values() {
            for b in ds.read_shard_batches(entry)? {
                rows.extend(batch_to_labels(&b)?.into_iter().filter(|r| r.status == Status::Ok));
            }
        }
        rows.sort_by_key(|r| (r.unit_index, r.sample_index));
        let mut set = LabelSet::default();
        for r in rows {
            let name = format!("{}:{}", root.display(), r.label_key);
            let depth = |png: &[u8]| -> Result<Vec<f32>> {
                let raw = decode_depth_png(png, Path::new(&name))?;
                if (raw.width, raw.height) != (r.width, r.height) {
                    return Err(Error::input(
                        &name,
                        format!("PNG is {}x{}, the row says {}x{}", raw.width, raw.height, r.width, r.height),
                    ));
                }
                Ok(raw
                    .data
                    .iter()
                    .map(|&mm| if mm == 0 || mm == u16::MAX { 0.0 } else { mm as f32 / 1000.0 })
                    .collect())
            };
            let (sparse, dense, keep) =
                (depth(&r.sparse_depth_png)?, depth(&r.dense_depth_png)?, decode_mask_png(&r.label_png, &name)?);
            if keep.len() != sparse.len() {
                return Err(Error::input(&name, "label and depth sizes differ"));
            }
            set.push(
                r.width as usize,
                r.height as usize,
                LabelExample {
                    key: r.label_key,
                    scene: r.scene,
                    unit_index: r.unit_index,
                    sparse,
                    dense,
                    keep,
                    window: LabelWindow {
                        first_frame: r.first_frame,
                        last_frame: r.last_frame,
                        reference_frame: r.reference_frame,
                        intrinsics: r.intrinsics,
                        t_target_from_reference: r.t_target_from_reference,
                    },
                },
                &name,
            )?;
        }
        Ok(set)
    }

    /// Reads several datasets into one set.
    pub fn open_all(roots: &[impl AsRef<Path>]) -> Result<LabelSet> {
        let mut all = LabelSet::default();
        for root in roots {
            let set = LabelSet::open(root.as_ref())?;
            for e in set.examples {
                let name = format!("{}:{}", root.as_ref().display(), e.key);
                all.push(set.width, set.height, e, &name)?;
            }
        }
        Ok(all)
    }

    fn push(&mut self, width: usize, height: usize, e: LabelExample, name: &str) -> Result<()> {
        if self.examples.is_empty() {
            (self.width, self.height) = (width, height);
        } else if (width, height) != (self.width, self.height) {
            return Err(Error::input(
                name,
                format!("example is {width}x{height}, the set is {}x{}", self.width, self.height),
            ));
        }
        self.examples.push(e);
        Ok(())
    }

    pub fn len(&self) -> usize {
        self.examples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.examples.is_empty()
    }

    /// Splits off a validation slice: the examples of the last `fraction` of the fused windows (at least
    /// one window; none when there is a single window), so no window has samples on both sides.
    pub fn split_windows(self, fraction: f64) -> (LabelSet, LabelSet) {
        let mut windows: Vec<(String, u64)> = self.examples.iter().map(|e| (e.scene.clone(), e.unit_index)).collect();
        windows.sort_by_key(|w| w.1);
        windows.dedup();
        let held = if windows.len() < 2 {
            0
        } else {
            ((windows.len() as f64 * fraction).ceil() as usize).clamp(1, windows.len() - 1)
        };
        let held: std::collections::HashSet<(String, u64)> = windows[windows.len() - held..].iter().cloned().collect();
        let (w, h) = (self.width, self.height);
        let (val, train): (Vec<_>, Vec<_>) =
            self.examples.into_iter().partition(|e| held.contains(&(e.scene.clone(), e.unit_index)));
        (LabelSet { width: w, height: h, examples: train }, LabelSet { width: w, height: h, examples: val })
    }

    /// Pixels with input depth, and those of them labelled "drop".
    pub fn pixel_counts(&self) -> (u64, u64) {
        let mut n = (0u64, 0u64);
        for e in &self.examples {
            for i in 0..e.sparse.len() {
                if e.has_depth(i) {
                    n.0 += 1;
                    n.1 += (!e.keep[i]) as u64;
                }
            }
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example(unit: u64, sample: u32) -> LabelExample {
        LabelExample {
            key: format!("s/window-{unit:06}#{sample}"),
            scene: "s".into(),
            unit_index: unit,
            sparse: vec![0.0, 1.0, 12.0],
            dense: vec![0.0; 3],
            keep: vec![true, false, true],
            window: LabelWindow::default(),
        }
    }

    #[test]
    fn the_validation_slice_takes_whole_windows_and_depth_beyond_10_m_is_missing() {
        let examples: Vec<LabelExample> = (0..10).flat_map(|u| (0..3).map(move |s| example(u, s))).collect();
        let set = LabelSet { width: 3, height: 1, examples };
        let (train, val) = set.split_windows(0.2);
        assert_eq!((train.len(), val.len()), (24, 6));
        assert!(val.examples.iter().all(|e| e.unit_index >= 8));
        // 12 m is beyond the network's 10 m range: no input depth there.
        assert_eq!(train.examples[0].input(), vec![0.0, 0.1, 0.0]);
        assert_eq!(train.pixel_counts(), (24, 24));
        let single = LabelSet { width: 3, height: 1, examples: vec![example(0, 0), example(0, 1)] };
        assert_eq!(single.split_windows(0.1).1.len(), 0);
    }

    #[test]
    fn mask_pngs_decode_to_keep_flags() {
        let png = crate::stages::pack::encode_mask_png(&[true, false, false, true], 2, 2).unwrap();
        assert_eq!(decode_mask_png(&png, "m.png").unwrap(), vec![true, false, false, true]);
        assert!(decode_mask_png(b"nope", "m.png").unwrap_err().to_string().contains("m.png"));
    }
}
