//! The ScanNet SensReader export layout: `depth/<i>.png` (millimetres), `pose/<i>.txt` (4×4
//! camera-to-world) and `intrinsic/intrinsic_depth.txt` (4×4).

use super::threedmatch::{first_readable_size, folder_name, list_dir};
use super::{text, FrameRef, PoseSource, Sequence};
use crate::error::{Error, Result};
use std::path::Path;

/// Raw depth units per metre of ScanNet depth PNGs (millimetres).
pub const DEPTH_SCALE: f32 = 1000.0;

/// Opens the export in `root`: frames `depth/<i>.png` sorted by `i`, keys `<root name>/frame-<i>`,
/// [`PoseSource::File`] when `pose/<i>.txt` exists (ScanNet writes `-inf` poses for frames where
/// tracking failed; loading such a frame fails with a message naming the pose file), image size from
/// the first readable depth PNG. Fails when the intrinsics file is missing or malformed, or when
/// `depth/` holds no `<number>.png`.
pub fn open(root: &Path) -> Result<Sequence> {
    let name = folder_name(root);
    let depth_dir = root.join("depth");
    let mut frames: Vec<(u64, String)> = list_dir(&depth_dir)?
        .into_iter()
        .filter_map(|(file, _)| {
            let stem = file.strip_suffix(".png")?;
            let i = stem.parse::<u64>().ok().filter(|_| stem.bytes().all(|b| b.is_ascii_digit()))?;
            Some((i, stem.to_string()))
        })
        .collect();
    if frames.is_empty() {
        return Err(Error::input(&depth_dir, "holds no <number>.png depth images"));
    }
    frames.sort();
    let (width, height) = first_readable_size(frames.iter().map(|(_, s)| depth_dir.join(format!("{s}.png"))))?;
    let intrinsics = text::read_intrinsics_file(&root.join("intrinsic").join("intrinsic_depth.txt"), width, height)?;
    let frames = frames
        .into_iter()
        .map(|(_, stem)| {
            let pose_path = root.join("pose").join(format!("{stem}.txt"));
            FrameRef {
                key: format!("{name}/frame-{stem}"),
                depth_path: depth_dir.join(format!("{stem}.png")),
                depth_scale: DEPTH_SCALE,
                intrinsics,
                pose: if pose_path.is_file() { PoseSource::File(pose_path) } else { PoseSource::None },
            }
        })
        .collect();
    Ok(Sequence { name, root: root.to_path_buf(), frames, poses: Default::default() })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sources::depth_png::write_depth_png;
    use nalgebra::{Isometry3, Vector3};

    const K_DEPTH: &str = "577.590698 0.000000 318.905426 0.000000\n0.000000 578.729797 242.683609 0.000000\n\
                           0.000000 0.000000 1.000000 0.000000\n0.000000 0.000000 0.000000 1.000000\n";

    fn scene(frames: &[(u32, bool)]) -> (tempfile::TempDir, std::path::PathBuf) {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("scene0000_00");
        std::fs::create_dir_all(root.join("intrinsic")).unwrap();
        std::fs::create_dir_all(root.join("pose")).unwrap();
        std::fs::write(root.join("intrinsic/intrinsic_depth.txt"), K_DEPTH).unwrap();
        for &(i, pose) in frames {
            write_depth_png(&root.join(format!("depth/{i}.png")), 16, 12, &[1500 + i as u16; 192]).unwrap();
            if pose {
                let p = Isometry3::new(Vector3::new(0.0, i as f64, 0.0), Vector3::zeros());
                text::write_pose_file(&root.join(format!("pose/{i}.txt")), &p).unwrap();
            }
        }
        (tmp, root)
    }

    #[test]
    fn frames_sort_numerically_with_keys_intrinsics_and_poses() {
        let (_tmp, root) = scene(&[(10, true), (2, true), (100, false), (9, true)]);
        std::fs::write(root.join("depth/notes.txt"), "x").unwrap();
        let s = open(&root).unwrap();
        assert_eq!(s.name, "scene0000_00");
        let keys: Vec<&str> = s.frames.iter().map(|f| f.key.as_str()).collect();
        assert_eq!(keys, ["scene0000_00/frame-2", "scene0000_00/frame-9", "scene0000_00/frame-10", "scene0000_00/frame-100"]);
        let k = s.frames[0].intrinsics;
        assert_eq!((k.fx, k.fy, k.cx, k.cy, k.width, k.height), (577.590698, 578.729797, 318.905426, 242.683609, 16, 12));
        assert_eq!(s.frames[2].pose, PoseSource::File(root.join("pose/10.txt")));
        assert_eq!(s.frames[3].pose, PoseSource::None);
        let f = s.frames[1].load().unwrap();
        assert_eq!(f.depth.at(0, 0), 1.509);
        assert_eq!(f.t_world_from_camera.unwrap().translation.vector.y, 9.0);
    }

    #[test]
    fn invalid_pose_fails_at_load_and_missing_parts_fail_at_open() {
        let (_tmp, root) = scene(&[(0, false)]);
        let inf = "-inf -inf -inf -inf\n-inf -inf -inf -inf\n-inf -inf -inf -inf\n-inf -inf -inf -inf\n";
        std::fs::write(root.join("pose/0.txt"), inf).unwrap();
        let s = open(&root).unwrap();
        let e = s.frames[0].load().unwrap_err().to_string();
        assert!(e.contains("0.txt") && e.contains("non-finite"), "{e}");

        std::fs::remove_file(root.join("intrinsic/intrinsic_depth.txt")).unwrap();
        let e = open(&root).unwrap_err().to_string();
        assert!(e.contains("intrinsic_depth.txt"), "{e}");

        let (_tmp2, root2) = scene(&[]);
        std::fs::create_dir(root2.join("depth")).unwrap();
        let e = open(&root2).unwrap_err().to_string();
        assert!(e.contains("depth") && e.contains("no <number>.png"), "{e}");
    }
}
