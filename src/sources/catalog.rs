//! The frames a build (or a label run, or a training set) draws from, in a fixed order: the `[source]`
//! and `[select]` config sections and the catalog they open.
//!
//! Unit `u` of a build is (frame `u / samples_per_frame`, sample `u % samples_per_frame`); the order
//! depends only on the config and the input listing. How units group into shards is
//! [`crate::shards::plan`].

use super::synthetic::{SyntheticConfig, SyntheticSequence};
use super::{open_sequences, CameraConfig, Frame, FrameRef, Layout, OpenOptions};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

/// Frame sources.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SourceConfig {
    /// Procedural indoor scenes rendered in memory (the exact oracle).
    Synthetic {
        /// Number of scenes (seeds `first_seed`, `first_seed + 1`, ...).
        scenes: u32,
        /// Seed of the first scene.
        #[serde(default)]
        first_seed: u64,
        /// Scene, sensor, intrinsics and trajectory length of every scene.
        #[serde(default)]
        synthetic: SyntheticConfig,
    },
    /// Depth sequences on disk.
    Directory {
        /// Folder holding the sequences (a relative path in a config file is relative to the file's folder).
        path: PathBuf,
        /// Folder layout; `auto` decides from marker files (`3dmatch`, `tum`, `scannet`); `folder` is a
        /// plain folder of depth PNGs and needs `intrinsics` and `depth_scale`.
        #[serde(default = "auto_layout")]
        layout: Layout,
        /// The depth camera `{ fx, fy, cx, cy }` in pixels of the stored images; replaces the layout's own.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        intrinsics: Option<CameraConfig>,
        /// Raw depth units per metre (1000: millimetres; TUM 5000); replaces the layout's own.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        depth_scale: Option<f32>,
        /// `folder` layout: a folder of `<image stem>.txt` 4×4 camera-to-world poses (optional; a build
        /// needs none, labels and fragments use only the frames that have one).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        poses: Option<PathBuf>,
    },
}

fn auto_layout() -> Layout {
    Layout::Auto
}

impl SourceConfig {
    /// How a `directory` source opens its folder (`None` for synthetic sources).
    pub fn open_options(&self) -> Option<OpenOptions> {
        match self {
            SourceConfig::Synthetic { .. } => None,
            SourceConfig::Directory { layout, intrinsics, depth_scale, poses, .. } => {
                Some(OpenOptions { layout: *layout, intrinsics: *intrinsics, depth_scale: *depth_scale, poses: poses.clone() })
            }
        }
    }

    /// Calls `visit` on each path of the section, with its key (see [`crate::config_paths`]).
    pub fn for_each_path(&mut self, visit: &mut dyn FnMut(&str, &mut PathBuf)) {
        if let SourceConfig::Directory { path, poses, .. } = self {
            visit("source.path", path);
            if let Some(p) = poses {
                visit("source.poses", p);
            }
        }
    }

    /// Checks ranges before any work starts; errors name the key under `source`.
    pub fn validate(&self) -> Result<()> {
        let bad = |k: &str, m: &str| Err(Error::config(k, m));
        match self {
            SourceConfig::Synthetic { scenes, synthetic, .. } => {
                if *scenes == 0 || *scenes > 1_000_000 {
                    return bad("source.scenes", "must be 1..=1000000");
                }
                if synthetic.frames == 0 || synthetic.frames > 100_000 {
                    return bad("source.synthetic.frames", "must be 1..=100000");
                }
                synthetic.scene.validate()?;
                synthetic.sensor.validate()?;
                synthetic.intrinsics.validate().map_err(|e| Error::config("source.synthetic.intrinsics", e.to_string()))
            }
            SourceConfig::Directory { path, .. } if path.as_os_str().is_empty() => bad("source.path", "must name a folder"),
            SourceConfig::Directory { .. } => self.open_options().expect("a directory source").validate("source."),
        }
    }
}

/// Frame selection within each sequence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SelectConfig {
    /// Take every `every`-th frame (50 = the first frame of each 50-frame 3DMatch fragment).
    pub every: usize,
    /// Index of the first frame taken.
    pub offset: usize,
    /// At most this many frames per sequence (0 = no limit).
    pub max_per_sequence: usize,
}

impl Default for SelectConfig {
    fn default() -> Self {
        SelectConfig { every: 1, offset: 0, max_per_sequence: 0 }
    }
}

impl SelectConfig {
    /// Checks the selection; errors name the key under `select`.
    pub fn validate(&self) -> Result<()> {
        if self.every == 0 {
            return Err(Error::config("select.every", "must be at least 1"));
        }
        Ok(())
    }
}

/// Where one catalog frame's depth comes from.
#[derive(Clone, Debug)]
pub enum FrameOrigin {
    /// A frame on disk.
    Disk(FrameRef),
    /// Frame `index` of the synthetic sequence with this `seed`, rendered on demand.
    Synthetic { seed: u64, index: usize },
}

/// One selected source frame.
#[derive(Clone, Debug)]
pub struct CatalogFrame {
    /// Sequence (scene) name.
    pub scene: String,
    /// Unique frame key.
    pub key: String,
    pub origin: FrameOrigin,
    /// Its sequence (index into [`Catalog::sequences`]) and its position there (0 = the sequence's first
    /// frame, selected or not).
    pub sequence: usize,
    pub position: usize,
}

/// Every frame of one sequence a catalog selects from, selected or not: the frames a scene around a
/// source frame is fused from ([`crate::scene`]).
#[derive(Clone, Debug)]
pub struct CatalogSequence {
    pub name: String,
    /// All frames, by position.
    pub frames: Vec<FrameOrigin>,
    /// Positions of the first and last selected frames: a scene takes its frames within this span only, so
    /// that a build restricted to some frames (a training split) never reads the frames around them.
    pub span: (usize, usize),
}

impl FrameOrigin {
    /// Whether the frame has a camera pose (synthetic frames always do).
    pub fn has_pose(&self) -> bool {
        match self {
            FrameOrigin::Disk(f) => f.has_pose(),
            FrameOrigin::Synthetic { .. } => true,
        }
    }
}

impl CatalogFrame {
    /// Whether the frame has a camera pose (synthetic frames always do).
    pub fn has_pose(&self) -> bool {
        self.origin.has_pose()
    }

    /// The depth file (or, for a synthetic frame, its key), for messages.
    pub fn depth_path(&self) -> PathBuf {
        match &self.origin {
            FrameOrigin::Disk(f) => f.depth_path.clone(),
            FrameOrigin::Synthetic { .. } => PathBuf::from(&self.key),
        }
    }
}

/// The selected frames of a build.
pub struct Catalog {
    pub frames: Vec<CatalogFrame>,
    /// The sequences the frames were selected from, every frame of each.
    pub sequences: Vec<CatalogSequence>,
    pub samples_per_frame: u32,
    synthetic: SyntheticConfig,
    /// The last synthetic sequence generated (units arrive in frame order, so one is enough).
    cache: Mutex<Option<Arc<SyntheticSequence>>>,
}

impl Catalog {
    /// Lists the frames of `source`, applying `select`; each frame makes `samples_per_frame` units.
    pub fn open(source: &SourceConfig, select: &SelectConfig, samples_per_frame: u32) -> Result<Catalog> {
        let mut frames = Vec::new();
        let mut sequences = Vec::new();
        // Selects from one sequence (its name, keys and origins by position).
        let mut add = |name: String, keys: Vec<String>, origins: Vec<FrameOrigin>| {
            let picked = select_indices(origins.len(), select);
            if let (Some(&first), Some(&last)) = (picked.first(), picked.last()) {
                for &i in &picked {
                    let (key, origin) = (keys[i].clone(), origins[i].clone());
                    frames.push(CatalogFrame { scene: name.clone(), key, origin, sequence: sequences.len(), position: i });
                }
                sequences.push(CatalogSequence { name, frames: origins, span: (first, last) });
            }
        };
        let synthetic = match source {
            SourceConfig::Synthetic { scenes, first_seed, synthetic } => {
                for s in 0..*scenes as u64 {
                    let seed = first_seed + s;
                    let scene = format!("synthetic-{seed}");
                    let keys = (0..synthetic.frames).map(|index| format!("{scene}/frame-{index:06}")).collect();
                    add(scene, keys, (0..synthetic.frames).map(|index| FrameOrigin::Synthetic { seed, index }).collect());
                }
                synthetic.clone()
            }
            SourceConfig::Directory { path, .. } => {
                for seq in open_sequences(path, source.open_options().expect("a directory source"))? {
                    let keys = seq.frames.iter().map(|f| f.key.clone()).collect();
                    add(seq.name, keys, seq.frames.into_iter().map(FrameOrigin::Disk).collect());
                }
                SyntheticConfig::default()
            }
        };
        if frames.is_empty() {
            return Err(Error::config("select", "no frame is selected from the source"));
        }
        Ok(Catalog { frames, sequences, samples_per_frame, synthetic, cache: Mutex::new(None) })
    }

    /// Total number of work units.
    pub fn units(&self) -> u64 {
        self.frames.len() as u64 * self.samples_per_frame as u64
    }

    /// (frame index, sample index) of unit `u`.
    pub fn unit(&self, u: u64) -> (usize, u32) {
        ((u / self.samples_per_frame as u64) as usize, (u % self.samples_per_frame as u64) as u32)
    }

    /// Decodes frame `i` (renders it, for synthetic frames).
    pub fn load(&self, i: usize) -> Result<Frame> {
        self.load_origin(&self.frames[i].origin)
    }

    /// Decodes the frame at `position` of sequence `sequence`, selected or not.
    pub fn load_at(&self, sequence: usize, position: usize) -> Result<Frame> {
        self.load_origin(&self.sequences[sequence].frames[position])
    }

    fn load_origin(&self, origin: &FrameOrigin) -> Result<Frame> {
        match origin {
            FrameOrigin::Disk(f) => f.load(),
            FrameOrigin::Synthetic { seed, index } => {
                let seq = {
                    let mut cache = self.cache.lock().expect("catalog cache");
                    match cache.as_ref().filter(|s| s.seed == *seed) {
                        Some(s) => s.clone(),
                        None => {
                            let s = Arc::new(SyntheticSequence::generate(&self.synthetic, *seed)?);
                            *cache = Some(s.clone());
                            s
                        }
                    }
                };
                Ok(seq.frame(*index))
            }
        }
    }
}

/// Indices `offset, offset + every, ...` below `n`, at most `max_per_sequence` of them (0 = all).
fn select_indices(n: usize, s: &SelectConfig) -> Vec<usize> {
    let it = (s.offset..n).step_by(s.every.max(1));
    if s.max_per_sequence == 0 {
        it.collect()
    } else {
        it.take(s.max_per_sequence).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selection_takes_every_nth_from_the_offset() {
        let s = SelectConfig { every: 50, offset: 0, max_per_sequence: 0 };
        assert_eq!(select_indices(120, &s), vec![0, 50, 100]);
        let s = SelectConfig { every: 2, offset: 1, max_per_sequence: 3 };
        assert_eq!(select_indices(100, &s), vec![1, 3, 5]);
    }
}
