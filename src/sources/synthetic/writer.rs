//! Writes a synthetic sequence in the flat 3DMatch layout (intrinsics, 16-bit depth PNGs, pose files).

use super::SyntheticSequence;
use crate::error::{Error, Result};
use crate::sources::{depth_png, text};
use std::path::Path;

/// `camera-intrinsics.txt`, then `frame-XXXXXX.depth.png` (millimetres) and `frame-XXXXXX.pose.txt`
/// (camera-to-world) for every frame, in `dir` (created if missing).
pub fn write_3dmatch(seq: &SyntheticSequence, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    text::write_intrinsics_file(&dir.join("camera-intrinsics.txt"), &seq.intrinsics)?;
    for (i, pose) in seq.poses.iter().enumerate() {
        let depth = seq.noisy_depth(i);
        let raw = depth.to_raw(1000.0);
        depth_png::write_depth_png(&dir.join(format!("frame-{i:06}.depth.png")), depth.width(), depth.height(), &raw)?;
        text::write_pose_file(&dir.join(format!("frame-{i:06}.pose.txt")), pose)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::{SyntheticConfig, SyntheticSequence};
    use crate::geometry::Intrinsics;
    use crate::sources::{depth_png, text};

    #[test]
    fn written_files_read_back_to_the_served_frames() {
        let config = SyntheticConfig {
            intrinsics: Intrinsics::new(150.0, 150.0, 80.0, 60.0, 160, 120).unwrap(),
            frames: 3,
            ..SyntheticConfig::default()
        };
        let seq = SyntheticSequence::generate(&config, 11).unwrap();
        let dir = tempfile::tempdir().unwrap();
        seq.write_3dmatch(dir.path()).unwrap();
        let k = text::read_intrinsics_file(&dir.path().join("camera-intrinsics.txt"), 160, 120).unwrap();
        assert_eq!(k, seq.intrinsics);
        for i in 0..3 {
            let frame = seq.frame(i);
            let png = depth_png::read_depth_png(&dir.path().join(format!("frame-{i:06}.depth.png"))).unwrap();
            assert_eq!(png.data, frame.depth.to_raw(1000.0));
            assert!(png.data.iter().filter(|v| **v > 0).count() > 160 * 120 / 2);
            let pose = text::read_pose_file(&dir.path().join(format!("frame-{i:06}.pose.txt"))).unwrap();
            let diff = pose.to_homogeneous() - seq.poses[i].to_homogeneous();
            assert!(diff.abs().max() < 1e-12, "pose {i} differs by {}", diff.abs().max());
        }
        assert!(!dir.path().join("frame-000003.depth.png").exists());
    }
}
