//! Windows of consecutive frames: the work units of the label pipeline.

use super::config::{LabelsConfig, Reference};
use crate::error::{Error, Result};
use crate::sources::{Catalog, SelectConfig};

/// One window: catalog indices of its consecutive frames and of its reference frame.
#[derive(Clone, Debug)]
pub struct Window {
    pub scene: String,
    /// `<scene>/window-XXXXXX` (window number within its sequence).
    pub key: String,
    pub frames: Vec<usize>,
    pub reference: usize,
}

/// Frames left out of the windows for want of a camera pose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Unposed {
    /// Distinct frames without a pose that fell in a window.
    pub frames: usize,
    /// Windows dropped because none of their frames has a pose.
    pub windows: usize,
}

/// Every frame of every sequence (no selection), and the windows over them. A window fuses only its
/// frames with a camera pose; its reference is the posed frame nearest the configured one, and a window
/// without any is dropped (both counted in [`Unposed`]). Under `strict` a frame without a pose in a window
/// is an error naming its file.
pub fn windows(config: &LabelsConfig, strict: bool) -> Result<(Catalog, Vec<Window>, Unposed)> {
    let catalog = Catalog::open(&config.source, &SelectConfig::default(), 1)?;
    let mut out = Vec::new();
    let mut unposed_frames = std::collections::BTreeSet::new();
    let mut unposed = Unposed::default();
    let mut start = 0;
    while start < catalog.frames.len() {
        let scene = catalog.frames[start].scene.clone();
        let end = (start..catalog.frames.len()).find(|&i| catalog.frames[i].scene != scene).unwrap_or(catalog.frames.len());
        let skip = config.window.first_frame;
        let n = (end - start).saturating_sub(skip);
        let (len, stride, max) = (config.window.frames, config.window.stride, config.window.max_windows);
        let mut w = 0;
        while w * stride + len <= n && (max == 0 || w < max) {
            let first = start + skip + w * stride;
            let wanted = match config.window.reference {
                Reference::First => first,
                Reference::Middle => first + len / 2,
            };
            let frames: Vec<usize> = (first..first + len).filter(|&i| catalog.frames[i].has_pose()).collect();
            if let Some(missing) = (first..first + len).find(|&i| !catalog.frames[i].has_pose()) {
                if strict {
                    return Err(Error::input(catalog.frames[missing].depth_path(), "frame has no camera pose (without --strict it is left out of its windows)"));
                }
                unposed_frames.extend((first..first + len).filter(|&i| !catalog.frames[i].has_pose()));
            }
            // Windows are numbered by their first frame's position in the sequence, so held-out windows
            // (a later `first_frame`) never share a key with training ones.
            let number = (skip + w * stride) / stride.max(1);
            match frames.iter().copied().min_by_key(|&i| i.abs_diff(wanted)) {
                Some(reference) => out.push(Window { key: format!("{scene}/window-{number:06}"), scene: scene.clone(), frames, reference }),
                None => unposed.windows += 1,
            }
            w += 1;
        }
        start = end;
    }
    unposed.frames = unposed_frames.len();
    if out.is_empty() {
        return Err(Error::config("window.frames", format!("no sequence has {} frames", config.window.frames)));
    }
    Ok((catalog, out, unposed))
}
