//! Training frames of the denoiser: single depth frames from any source the build reads, mapped to the
//! working resolution exactly as the build's ingest does, in network space.

use crate::error::{Error, Result};
use crate::nn::correction::normalise_depth;
use crate::pipeline::catalog::Catalog;
use crate::pipeline::config::BuildConfig;
use std::path::{Path, PathBuf};

/// Network value of a metric depth: `2·z/10 − 1`, with missing, non-finite and > 10 m as −1.
pub fn to_network(z: f32) -> f32 {
    2.0 * normalise_depth(z) - 1.0
}

/// Metric depth of a network value (the inverse of [`to_network`] on (−1, 1]; −1 and below is missing).
pub fn from_network(v: f32) -> f32 {
    if v > -1.0 {
        (v + 1.0) * 0.5 * crate::nn::correction::DEPTH_SCALE_M
    } else {
        0.0
    }
}

/// One training frame.
#[derive(Clone, Debug)]
pub struct TrainFrame {
    /// Row-major network-space depth.
    pub depth: Vec<f32>,
    /// Working-resolution `[fx, fy, cx, cy]`.
    pub intrinsics: [f64; 4],
    pub key: String,
}

/// Every training frame, all of one size.
#[derive(Clone, Debug, Default)]
pub struct FrameSet {
    pub width: usize,
    pub height: usize,
    pub frames: Vec<TrainFrame>,
}

/// The build config a data argument stands for: a pipeline TOML (its `[source]`, `[select]` and
/// `[working]` are used), or a folder of depth sequences (every frame, the default working resolution).
pub fn data_config(input: &Path) -> Result<BuildConfig> {
    if input.is_dir() {
        let text = format!("[source]\nkind = \"directory\"\npath = {:?}\n", input.display().to_string());
        BuildConfig::from_toml(&text, &input.display().to_string())
    } else {
        let text = std::fs::read_to_string(input).map_err(|e| Error::io(input, e))?;
        BuildConfig::from_toml(&text, &input.display().to_string())
    }
}

impl FrameSet {
    /// Loads the frames of every input (see [`data_config`]); `progress` shows a bar.
    pub fn load(inputs: &[PathBuf], progress: bool) -> Result<FrameSet> {
        let mut set = FrameSet::default();
        for input in inputs {
            let config = data_config(input)?;
            let catalog = Catalog::open(&config)?;
            let size = config.working.size as usize;
            if !set.frames.is_empty() && (set.width, set.height) != (size, size) {
                return Err(Error::config(
                    "--data",
                    format!("{} has working size {size}, earlier inputs {}", input.display(), set.width),
                ));
            }
            (set.width, set.height) = (size, size);
            let bar = crate::export::rows::progress_bar(catalog.frames.len() as u64, progress, "frames");
            for i in 0..catalog.frames.len() {
                let frame = catalog.load(i)?;
                let (depth, k) = config.working.map_frame(&frame)?;
                set.frames.push(TrainFrame {
                    depth: depth.data().iter().map(|z| to_network(*z)).collect(),
                    intrinsics: k.as_vector(),
                    key: frame.key.clone(),
                });
                bar.inc(1);
            }
            bar.finish_and_clear();
        }
        if set.frames.is_empty() {
            return Err(Error::config("--data", "no training frame"));
        }
        Ok(set)
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn network_space_round_trips_and_marks_missing_depth() {
        for z in [0.5f32, 1.234, 3.0, 9.99] {
            assert!((from_network(to_network(z)) - z).abs() < 1e-5);
        }
        for z in [0.0f32, -1.0, 11.0, f32::NAN] {
            assert_eq!(to_network(z), -1.0);
            assert_eq!(from_network(to_network(z)), 0.0);
        }
    }
}
