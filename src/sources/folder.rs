//! A plain folder of 16-bit depth PNGs (a phone, a RealSense, any export without a dataset layout): the
//! intrinsics and the depth scale come from the options (`[source]` keys or command-line flags), poses
//! optionally from a folder of `<image stem>.txt` 4×4 camera-to-world matrices.

use super::threedmatch::{first_readable_size, folder_name, list_dir};
use super::{FrameRef, OpenOptions, PoseCounts, PoseSource, Sequence};
use crate::error::{Error, Result};
use std::cmp::Ordering;
use std::path::Path;

/// Opens the `*.png` files directly in `root` (not in sub-folders) as one sequence, in natural order of
/// their names (`2.png` before `10.png`), keys `<root name>/<stem>`. A frame has a pose when
/// `options.poses` holds `<stem>.txt` (or `<stem>.pose.txt`). Fails, naming the folder, when it holds no
/// PNG, and, naming the key, when the intrinsics or the depth scale are missing.
pub fn open(root: &Path, options: &OpenOptions) -> Result<Sequence> {
    let camera = options.intrinsics.ok_or_else(|| Error::config("source.intrinsics", "the \"folder\" layout needs the depth camera's fx, fy, cx, cy"))?;
    let depth_scale = options.depth_scale.ok_or_else(|| Error::config("source.depth_scale", "the \"folder\" layout needs the raw depth units per metre (1000 for millimetres)"))?;
    let mut images: Vec<(String, std::path::PathBuf)> = list_dir(root)?
        .into_iter()
        .filter_map(|(name, path)| Some((name.strip_suffix(".png").or_else(|| name.strip_suffix(".PNG"))?.to_string(), path)))
        .filter(|(_, path)| path.is_file())
        .collect();
    if images.is_empty() {
        return Err(Error::input(root, "holds no .png depth images"));
    }
    images.sort_by(|a, b| natural_cmp(&a.0, &b.0));
    let size = first_readable_size(images.iter().map(|(_, p)| p))?;
    let intrinsics = camera.at_size(size).map_err(|e| Error::config("source.intrinsics", e.to_string()))?;
    if let Some(p) = &options.poses {
        if !p.is_dir() {
            return Err(Error::input(p, "the poses folder (source.poses) does not exist"));
        }
    }
    let name = folder_name(root);
    let frames = images
        .into_iter()
        .map(|(stem, depth_path)| {
            let pose = options
                .poses
                .as_ref()
                .and_then(|dir| [format!("{stem}.txt"), format!("{stem}.pose.txt")].into_iter().map(|n| dir.join(n)).find(|p| p.is_file()))
                .map_or(PoseSource::None, PoseSource::File);
            FrameRef { key: format!("{name}/{stem}"), depth_path, depth_scale, intrinsics, pose }
        })
        .collect();
    Ok(Sequence { name, root: root.to_path_buf(), frames, poses: PoseCounts::default() })
}

/// Compares names by runs: digit runs by their number, the rest as text (`img2` < `img10`).
fn natural_cmp(a: &str, b: &str) -> Ordering {
    fn runs(s: &str) -> Vec<(bool, &str)> {
        let mut out = Vec::new();
        let mut start = 0;
        let bytes = s.as_bytes();
        for i in 1..=bytes.len() {
            if i == bytes.len() || bytes[i].is_ascii_digit() != bytes[start].is_ascii_digit() {
                out.push((bytes[start].is_ascii_digit(), &s[start..i]));
                start = i;
            }
        }
        out
    }
    let (ra, rb) = (runs(a), runs(b));
    for (x, y) in ra.iter().zip(&rb) {
        let o = match (x, y) {
            ((true, x), (true, y)) => {
                let (tx, ty) = (x.trim_start_matches('0'), y.trim_start_matches('0'));
                tx.len().cmp(&ty.len()).then(tx.cmp(ty)).then(x.len().cmp(&y.len()))
            }
            ((_, x), (_, y)) => x.cmp(y),
        };
        if o != Ordering::Equal {
            return o;
        }
    }
    ra.len().cmp(&rb.len()).then(a.cmp(b))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sources::depth_png::write_depth_png;
    use crate::sources::{text, CameraConfig, Layout};
    use nalgebra::{Isometry3, Vector3};

    #[test]
    fn natural_order_puts_numbers_by_value() {
        let mut v = vec!["img10", "img2", "img1", "a", "img02", "b1"];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(v, ["a", "b1", "img1", "img2", "img02", "img10"]);
    }

    #[test]
    fn lists_pngs_with_the_given_camera_scale_and_optional_poses() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("phone-scan");
        for (i, name) in ["10", "2", "9"].iter().enumerate() {
            write_depth_png(&root.join(format!("{name}.png")), 8, 6, &[1000 + i as u16; 48]).unwrap();
        }
        std::fs::write(root.join("notes.txt"), "not an image").unwrap();
        let poses = tmp.path().join("poses");
        std::fs::create_dir(&poses).unwrap();
        text::write_pose_file(&poses.join("9.txt"), &Isometry3::new(Vector3::new(0.0, 0.0, 1.5), Vector3::zeros())).unwrap();

        let camera = CameraConfig { fx: 600.0, fy: 610.0, cx: 3.5, cy: 2.5 };
        let options = OpenOptions { layout: Layout::Folder, intrinsics: Some(camera), depth_scale: Some(4000.0), poses: Some(poses) };
        let seqs = crate::sources::open_sequences(&root, options.clone()).unwrap();
        let s = &seqs[0];
        let keys: Vec<&str> = s.frames.iter().map(|f| f.key.as_str()).collect();
        assert_eq!(keys, ["phone-scan/2", "phone-scan/9", "phone-scan/10"]);
        let k = s.frames[0].intrinsics;
        assert_eq!((k.fx, k.fy, k.cx, k.cy, k.width, k.height), (600.0, 610.0, 3.5, 2.5, 8, 6));
        assert_eq!(s.poses.without, 2);
        let f = s.frames[1].load().unwrap(); // 9.png was written third: 1002 raw units at 4000 per metre
        assert!((f.depth.at(0, 0) - 1002.0 / 4000.0).abs() < 1e-6);
        assert_eq!(f.t_world_from_camera.unwrap().translation.vector.z, 1.5);
        assert!(s.frames[0].load().unwrap().t_world_from_camera.is_none());

        let e = open(&root, &OpenOptions { depth_scale: None, ..options.clone() }).unwrap_err().to_string();
        assert!(e.contains("source.depth_scale"), "{e}");
        let empty = tmp.path().join("empty");
        std::fs::create_dir(&empty).unwrap();
        let e = open(&empty, &options).unwrap_err().to_string();
        assert!(e.contains("empty") && e.contains("no .png"), "{e}");
    }
}
