//! The command-line form of [`OpenOptions`]: how a command that reads sequence folders opens them
//! (`--layout`, and for a plain folder `--intrinsics`, `--depth-scale`, `--poses`).

use crate::error::Result;
use crate::sources::{CameraConfig, Layout, OpenOptions};
use std::path::PathBuf;

#[derive(Clone, Debug, Default, clap::Args)]
pub struct SequenceArgs {
    /// Folder layout (auto: 3dmatch, tum or scannet from marker files; folder: a plain folder of depth
    /// PNGs, which needs --intrinsics and --depth-scale).
    #[arg(long, value_enum, default_value = "auto")]
    pub layout: Layout,
    /// Depth camera intrinsics `fx,fy,cx,cy` in pixels of the stored images (replaces the layout's own).
    #[arg(long, value_parser = CameraConfig::parse)]
    pub intrinsics: Option<CameraConfig>,
    /// Raw depth units per metre (1000 for millimetres; replaces the layout's own).
    #[arg(long)]
    pub depth_scale: Option<f32>,
    /// --layout folder: a folder of `<image stem>.txt` 4x4 camera-to-world poses.
    #[arg(long)]
    pub poses: Option<PathBuf>,
}

impl SequenceArgs {
    /// The checked options.
    pub fn options(&self) -> Result<OpenOptions> {
        let o = OpenOptions { layout: self.layout, intrinsics: self.intrinsics, depth_scale: self.depth_scale, poses: self.poses.clone() };
        o.validate("--")?;
        Ok(o)
    }
}
