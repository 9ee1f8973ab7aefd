//! Ingest: depth frames with intrinsics and camera-to-world poses from the supported layouts.
//!
//! Every reader lists a sequence's frames as [`FrameRef`]s without decoding them; [`FrameRef::load`]
//! decodes one frame into a [`Frame`]. Errors name the file and the problem.

pub mod catalog;
pub mod depth_png;
pub mod folder;
pub mod scannet;
pub mod synthetic;
pub mod text;
pub mod threedmatch;
pub mod tum;

use crate::error::{Error, Result};
use crate::geometry::{DepthMap, Intrinsics};
use nalgebra::Isometry3;
use std::path::{Path, PathBuf};

pub use catalog::{Catalog, SelectConfig, SourceConfig};
pub use options::{CameraConfig, OpenOptions, PoseCounts};

mod options;

/// Raw depth values that mean "no measurement" in 3DMatch / 7-Scenes / SUN3D / ScanNet PNGs.
pub const INVALID_RAW_DEPTH: [u16; 2] = [0, 65535];

/// Where a frame's camera-to-world pose comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum PoseSource {
    /// The sequence has no pose for this frame.
    None,
    /// A text file holding a row-major 4×4 camera-to-world matrix (3DMatch `frame-*.pose.txt`, ScanNet `pose/*.txt`).
    File(PathBuf),
    /// Already known (TUM `groundtruth.txt`, synthetic sequences).
    Known(Isometry3<f64>),
}

/// One frame of a sequence, listed but not decoded.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRef {
    /// Unique key within a dataset, e.g. `redkitchen/seq-01/frame-000042`.
    pub key: String,
    /// The 16-bit depth PNG.
    pub depth_path: PathBuf,
    /// Raw depth units per metre (1000 for millimetres, 5000 for TUM).
    pub depth_scale: f32,
    /// Intrinsics of the depth image at its stored size.
    pub intrinsics: Intrinsics,
    pub pose: PoseSource,
}

/// A decoded frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub key: String,
    /// Depth in metres, 0 where invalid.
    pub depth: DepthMap,
    pub intrinsics: Intrinsics,
    /// Camera-to-world pose, when the sequence has one.
    pub t_world_from_camera: Option<Isometry3<f64>>,
    /// The depth file (for provenance).
    pub depth_path: PathBuf,
    /// blake3 of the depth file's bytes, hex (for provenance).
    pub content_hash: String,
}

impl FrameRef {
    /// Reads and decodes the depth PNG and the pose. Fails, naming the file, when the PNG is missing,
    /// truncated, not 16-bit grayscale, or not the size of the intrinsics, or when the pose is missing,
    /// unparsable, non-finite or not rigid.
    pub fn load(&self) -> Result<Frame> {
        let bytes = std::fs::read(&self.depth_path).map_err(|e| Error::io(&self.depth_path, e))?;
        let content_hash = blake3::hash(&bytes).to_hex().to_string();
        let raw = depth_png::decode_depth_png(&bytes, &self.depth_path)?;
        if (raw.width, raw.height) != (self.intrinsics.width, self.intrinsics.height) {
            return Err(Error::input(
                &self.depth_path,
                format!(
                    "depth image is {}x{} but the intrinsics are for {}x{}",
                    raw.width, raw.height, self.intrinsics.width, self.intrinsics.height
                ),
            ));
        }
        let depth = DepthMap::from_raw(raw.width, raw.height, &raw.data, self.depth_scale, &INVALID_RAW_DEPTH)?;
        let t_world_from_camera = match &self.pose {
            PoseSource::None => None,
            PoseSource::Known(p) => Some(*p),
            PoseSource::File(path) => Some(text::read_pose_file(path)?),
        };
        Ok(Frame {
            key: self.key.clone(),
            depth,
            intrinsics: self.intrinsics,
            t_world_from_camera,
            depth_path: self.depth_path.clone(),
            content_hash,
        })
    }

    /// Whether the sequence gives this frame a pose (a pose file, or a known pose). A pose file can
    /// still fail to load (unparsable, non-finite): that is bad input, not a missing pose.
    pub fn has_pose(&self) -> bool {
        self.pose != PoseSource::None
    }
}

/// An ordered list of frames from one capture.
#[derive(Clone, Debug, PartialEq)]
pub struct Sequence {
    /// Name used as the first part of frame keys.
    pub name: String,
    pub root: PathBuf,
    pub frames: Vec<FrameRef>,
    /// How the frames got their poses (TUM: exact, interpolated, left without), for summaries.
    pub poses: PoseCounts,
}

impl Sequence {
    /// How many of `frames` (indices) have no pose. Under `strict` one is an error naming its file, for
    /// the commands whose pairs take their truth from the poses (fragments, labels, real pairs); without
    /// it they leave those frames out and report the count.
    pub fn unposed(&self, frames: impl IntoIterator<Item = usize>, strict: bool) -> Result<usize> {
        let missing: Vec<usize> = frames.into_iter().filter(|&f| !self.frames[f].has_pose()).collect();
        match missing.first() {
            Some(&f) if strict => Err(Error::input(
                &self.frames[f].depth_path,
                format!("frame has no camera pose ({} of the frames used from {} have none; without --strict they are left out)", missing.len(), self.name),
            )),
            _ => Ok(missing.len()),
        }
    }
}

/// The layouts [`open_sequences`] recognises.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Layout {
    /// Decide from the folder's content (never `folder`: a plain folder needs its intrinsics given).
    #[default]
    Auto,
    /// 3DMatch / 7-Scenes / SUN3D: `frame-XXXXXX.depth.png` + `.pose.txt`, flat or in `seq-XX/`, in one
    /// scene folder or in each scene folder of the given one.
    #[value(name = "3dmatch")]
    #[serde(rename = "3dmatch")]
    ThreeDMatch,
    /// TUM RGB-D: `depth.txt`, `depth/*.png` (scale 5000), `groundtruth.txt`.
    Tum,
    /// ScanNet export: `depth/`, `pose/`, `intrinsic/intrinsic_depth.txt`.
    Scannet,
    /// A plain folder of 16-bit depth PNGs; intrinsics and depth scale come from the config
    /// (`source.intrinsics`, `source.depth_scale`), poses optionally from `source.poses`.
    Folder,
}

/// Opens the sequences under `root` with `options` (a [`Layout`] alone converts: the layout's own
/// intrinsics, depth scale and poses). `Auto` looks at the folder; the intrinsics and depth scale of the
/// options, when given, replace the layout's own.
pub fn open_sequences(root: &Path, options: impl Into<OpenOptions>) -> Result<Vec<Sequence>> {
    let options = options.into();
    let layout = match options.layout {
        Layout::Auto => detect_layout(root)?,
        l => l,
    };
    let camera = |size: (u32, u32)| options.intrinsics.map(|c| c.at_size(size)).transpose();
    let mut sequences = match layout {
        Layout::ThreeDMatch => threedmatch::open(root)?,
        Layout::Tum => vec![tum::open(root, None)?],
        Layout::Scannet => vec![scannet::open(root)?],
        Layout::Folder => vec![folder::open(root, &options)?],
        Layout::Auto => unreachable!(),
    };
    for seq in &mut sequences {
        for f in &mut seq.frames {
            if let Some(k) = camera((f.intrinsics.width, f.intrinsics.height)).map_err(|e| Error::config("source.intrinsics", e.to_string()))? {
                f.intrinsics = k;
            }
            if let Some(scale) = options.depth_scale {
                f.depth_scale = scale;
            }
        }
        seq.poses.without = seq.frames.iter().filter(|f| !f.has_pose()).count();
    }
    Ok(sequences)
}

/// Guesses the layout of `root` from marker files.
pub fn detect_layout(root: &Path) -> Result<Layout> {
    if !root.is_dir() {
        return Err(Error::input(root, "not a directory"));
    }
    if root.join("depth.txt").is_file() {
        Ok(Layout::Tum)
    } else if root.join("intrinsic").join("intrinsic_depth.txt").is_file() {
        Ok(Layout::Scannet)
    } else {
        Ok(Layout::ThreeDMatch)
    }
}
