//! Training frames of the denoiser: single depth frames from any source the build reads, mapped to the
//! working resolution exactly as the build's ingest does, in network space.

use crate::error::{Error, Result};
use crate::nn::space::to_network;
use crate::pipeline::BuildConfig;
use crate::sources::Catalog;
use std::path::{Path, PathBuf};

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
    if input.to_str().is_some_and(|s| s.contains("://")) {
        return Err(Error::config(
            "--data",
            format!(
                "{}: a URL; --data takes a pipeline TOML or a local folder of depth sequences (source frames are read \
                 from local folders; datasets of pairs and labels can live on object stores)",
                input.display()
            ),
        ));
    }
    if input.is_dir() {
        let text = format!("[source]\nkind = \"directory\"\npath = {:?}\n", input.display().to_string());
        BuildConfig::from_toml(&text, &input.display().to_string())
    } else {
        // Its relative paths are relative to its folder.
        crate::pipeline::load::load_toml(input, &[])
    }
}

impl FrameSet {
    /// Loads the frames of every input (see [`data_config`]); `progress` shows a bar.
    pub fn load(inputs: &[PathBuf], progress: bool) -> Result<FrameSet> {
        let mut set = FrameSet::default();
        for input in inputs {
            let config = data_config(input)?;
            let catalog = Catalog::open(&config.source, &config.select, 1)?;
            let size = config.working.size as usize;
            if !set.frames.is_empty() && (set.width, set.height) != (size, size) {
                return Err(Error::config(
                    "--data",
                    format!("{} has working size {size}, earlier inputs {}", input.display(), set.width),
                ));
            }
            (set.width, set.height) = (size, size);
            let bar = crate::runtime::progress::bar(catalog.frames.len() as u64, progress, "frames");
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
