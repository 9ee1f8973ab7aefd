//! How a sequence folder is opened ([`OpenOptions`]: layout, and the intrinsics, depth scale and poses a
//! plain folder needs or a layout's own can be replaced by), and how its frames got their poses
//! ([`PoseCounts`]).

use super::Layout;
use crate::error::{Error, Result};
use crate::geometry::Intrinsics;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// A pinhole depth camera in pixels of the stored depth images (their size is read from the images).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Focal lengths, pixels.
    pub fx: f64,
    pub fy: f64,
    /// Principal point, pixels, as a `camera-intrinsics.txt` gives it.
    pub cx: f64,
    pub cy: f64,
}

impl CameraConfig {
    /// The intrinsics for images of `(width, height)`.
    pub fn at_size(self, (width, height): (u32, u32)) -> Result<Intrinsics> {
        Intrinsics::new(self.fx, self.fy, self.cx, self.cy, width, height)
    }

    /// Parses `fx,fy,cx,cy` (the command-line form).
    pub fn parse(s: &str) -> std::result::Result<CameraConfig, String> {
        let v: Vec<f64> = s.split(',').map(|t| t.trim().parse::<f64>().map_err(|_| format!("`{t}` is not a number"))).collect::<std::result::Result<_, _>>()?;
        match v[..] {
            [fx, fy, cx, cy] => {
                let c = CameraConfig { fx, fy, cx, cy };
                c.at_size((1, 1)).map_err(|e| e.to_string())?;
                Ok(c)
            }
            _ => Err(format!("expected fx,fy,cx,cy (4 numbers), found {}", v.len())),
        }
    }
}

/// How [`super::open_sequences`] reads a folder.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OpenOptions {
    pub layout: Layout,
    /// Replaces the layout's intrinsics (required by [`Layout::Folder`]).
    pub intrinsics: Option<CameraConfig>,
    /// Raw depth units per metre; replaces the layout's (required by [`Layout::Folder`]).
    pub depth_scale: Option<f32>,
    /// [`Layout::Folder`]: a folder of `<image stem>.txt` 4×4 camera-to-world poses (frames without one
    /// have no pose).
    pub poses: Option<PathBuf>,
}

impl From<Layout> for OpenOptions {
    fn from(layout: Layout) -> OpenOptions {
        OpenOptions { layout, ..OpenOptions::default() }
    }
}

impl OpenOptions {
    /// Checks the values (the error names `key_prefix` + the field, e.g. `source.depth_scale`).
    pub fn validate(&self, key_prefix: &str) -> Result<()> {
        if let Some(s) = self.depth_scale {
            if !(s.is_finite() && s > 0.0) {
                return Err(Error::config(format!("{key_prefix}depth_scale"), "must be a positive number of raw units per metre"));
            }
        }
        if let Some(c) = self.intrinsics {
            c.at_size((1, 1)).map_err(|e| Error::config(format!("{key_prefix}intrinsics"), e.to_string()))?;
        }
        if self.layout == Layout::Folder && (self.intrinsics.is_none() || self.depth_scale.is_none()) {
            return Err(Error::config(
                format!("{key_prefix}layout"),
                "the \"folder\" layout needs the intrinsics and the depth scale (intrinsics = { fx, fy, cx, cy } and depth_scale, raw units per metre)",
            ));
        }
        if self.poses.is_some() && self.layout != Layout::Folder {
            return Err(Error::config(format!("{key_prefix}poses"), "is for the \"folder\" layout (the other layouts carry their poses)"));
        }
        Ok(())
    }
}

/// How a sequence's frames got their camera poses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PoseCounts {
    /// TUM: frames with a ground-truth sample at their timestamp.
    pub exact: usize,
    /// TUM: frames whose pose is interpolated between the two samples around their timestamp.
    pub interpolated: usize,
    /// Frames without a pose (any layout).
    pub without: usize,
}

impl PoseCounts {
    /// Whether the poses were matched to the frames by timestamp (TUM), so the counts are worth printing.
    pub fn from_timestamps(&self) -> bool {
        self.exact + self.interpolated > 0
    }

    /// One line for summaries, e.g. `700 exact, 19 interpolated, 3 without a pose`; empty when every
    /// frame of a layout without timestamps has its pose.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if self.from_timestamps() {
            parts.push(format!("{} poses exact, {} interpolated", self.exact, self.interpolated));
        }
        if self.without > 0 {
            parts.push(format!("{} frame(s) without a pose", self.without));
        }
        parts.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_parses_and_folder_needs_intrinsics_and_scale() {
        assert_eq!(CameraConfig::parse("525, 525,319.5,239.5").unwrap(), CameraConfig { fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 });
        assert!(CameraConfig::parse("525,525,319.5").unwrap_err().contains("4 numbers"));
        assert!(CameraConfig::parse("-1,525,319.5,239.5").is_err());
        let e = OpenOptions::from(Layout::Folder).validate("source.").unwrap_err().to_string();
        assert!(e.contains("source.layout") && e.contains("depth_scale"), "{e}");
        let ok = OpenOptions { layout: Layout::Folder, intrinsics: CameraConfig::parse("1,1,0,0").ok(), depth_scale: Some(1000.0), poses: None };
        ok.validate("").unwrap();
        let e = OpenOptions { depth_scale: Some(0.0), ..ok.clone() }.validate("source.").unwrap_err().to_string();
        assert!(e.contains("source.depth_scale"), "{e}");
        let e = OpenOptions { layout: Layout::Tum, poses: Some("p".into()), ..ok }.validate("").unwrap_err().to_string();
        assert!(e.contains("poses") && e.contains("folder"), "{e}");
    }
}
