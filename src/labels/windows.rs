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

/// Every frame of every sequence (no selection), and the windows over them.
pub fn windows(config: &LabelsConfig) -> Result<(Catalog, Vec<Window>)> {
    let catalog = Catalog::open(&config.source, &SelectConfig::default(), 1)?;
    let mut out = Vec::new();
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
            let frames: Vec<usize> = (first..first + len).collect();
            let reference = match config.window.reference {
                Reference::First => frames[0],
                Reference::Middle => frames[len / 2],
            };
            // Windows are numbered by their first frame's position in the sequence, so held-out windows
            // (a later `first_frame`) never share a key with training ones.
            let number = (skip + w * stride) / stride.max(1);
            out.push(Window { key: format!("{scene}/window-{number:06}"), scene: scene.clone(), frames, reference });
            w += 1;
        }
        start = end;
    }
    if out.is_empty() {
        return Err(Error::config("window.frames", format!("no sequence has {} frames", config.window.frames)));
    }
    Ok((catalog, out))
}
