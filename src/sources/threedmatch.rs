//! The 3DMatch / 7-Scenes / SUN3D RGB-D layout: `frame-XXXXXX.depth.png` + `frame-XXXXXX.pose.txt`,
//! flat in the root or in `seq-XX/` folders, with a 3×3 `camera-intrinsics.txt` in the root; or a folder
//! of such scene folders (3DMatch's RGB-D download unpacked side by side).

use super::{text, FrameRef, PoseSource, Sequence};
use crate::error::{Error, Result};
use crate::geometry::Intrinsics;
use std::path::{Path, PathBuf};

/// Raw depth units per metre of the layout (millimetres).
pub const DEPTH_SCALE: f32 = 1000.0;

/// Names of the intrinsics file, in the order they are tried (`intrinsics.K.txt` is the name used by
/// the older tsdf-fusion samples).
pub const INTRINSICS_NAMES: [&str; 2] = ["camera-intrinsics.txt", "intrinsics.K.txt"];

/// Lists the sequences under `root`: one per `seq-*` sub-folder holding frames (in name order), plus
/// one for frames lying directly in `root` (listed first). Frames are sorted by frame number; keys are
/// `<root name>/<seq folder>/frame-XXXXXX` (`<root name>/frame-XXXXXX` for flat frames). A frame
/// without a pose file gets [`PoseSource::None`].
///
/// When `root` itself holds no frames (neither flat nor in `seq-*`), it is a folder of scenes: every
/// other sub-folder (in name order) is opened as a scene the same way, one level deep, with keys
/// `<scene folder>/<seq folder>/frame-XXXXXX`; sub-folders without frames are skipped.
///
/// Intrinsics come from the sequence folder's own intrinsics file when it has one, else from the
/// scene's; the image size is read from the PNG header of the sequence's first readable frame.
/// Fails when `root` cannot be read, when there are no frames at all, or when a sequence has no
/// intrinsics file (the error names the scene folder).
pub fn open(root: &Path) -> Result<Vec<Sequence>> {
    let mut sequences = open_scene(root)?;
    if sequences.is_empty() {
        let mut scenes: Vec<(String, PathBuf)> =
            list_dir(root)?.into_iter().filter(|(name, path)| !name.starts_with("seq-") && path.is_dir()).collect();
        scenes.sort();
        for (_, scene) in scenes {
            sequences.extend(open_scene(&scene)?);
        }
    }
    if sequences.is_empty() {
        return Err(Error::input(
            root,
            "no frame-XXXXXX.depth.png files here, in seq-* sub-folders, or in scene folders holding them (for a plain folder \
             of depth PNGs use the \"folder\" layout with the intrinsics and the depth scale: `layout = \"folder\"` in [source], or \
             --layout folder --intrinsics fx,fy,cx,cy --depth-scale N)",
        ));
    }
    Ok(sequences)
}

/// The sequences of one scene folder (flat frames and `seq-*` sub-folders); empty when it has none.
fn open_scene(root: &Path) -> Result<Vec<Sequence>> {
    let root_name = folder_name(root);
    let mut folders: Vec<(PathBuf, String)> = vec![(root.to_path_buf(), String::new())];
    let mut subs: Vec<String> = list_dir(root)?
        .into_iter()
        .filter(|(name, path)| name.starts_with("seq-") && path.is_dir())
        .map(|(name, _)| name)
        .collect();
    subs.sort();
    folders.extend(subs.into_iter().map(|s| (root.join(&s), s)));

    let mut sequences = Vec::new();
    for (dir, sub) in folders {
        let frames = list_frames(&dir)?;
        if frames.is_empty() {
            continue;
        }
        let name = if sub.is_empty() { root_name.clone() } else { format!("{root_name}/{sub}") };
        let k_path = INTRINSICS_NAMES
            .iter()
            .flat_map(|n| [dir.join(n), root.join(n)])
            .find(|p| p.is_file())
            .ok_or_else(|| {
                Error::input(root, format!("no intrinsics file ({} or {}) for the frames of {}", INTRINSICS_NAMES[0], INTRINSICS_NAMES[1], dir.display()))
            })?;
        let (width, height) = first_readable_size(frames.iter().map(|(_, p)| p))?;
        let intrinsics = text::read_intrinsics_file(&k_path, width, height)?;
        let frames = frames
            .into_iter()
            .map(|(stem, depth_path)| frame_ref(&name, &dir, stem, depth_path, intrinsics))
            .collect();
        sequences.push(Sequence { name, root: dir, frames, poses: Default::default() });
    }
    Ok(sequences)
}

fn frame_ref(seq_name: &str, dir: &Path, stem: String, depth_path: PathBuf, intrinsics: Intrinsics) -> FrameRef {
    let pose_path = dir.join(format!("{stem}.pose.txt"));
    let pose = if pose_path.is_file() { PoseSource::File(pose_path) } else { PoseSource::None };
    FrameRef { key: format!("{seq_name}/{stem}"), depth_path, depth_scale: DEPTH_SCALE, intrinsics, pose }
}

/// `(stem, path)` of the `frame-<digits>.depth.png` files of `dir`, sorted by frame number.
fn list_frames(dir: &Path) -> Result<Vec<(String, PathBuf)>> {
    let mut frames: Vec<(u64, String, PathBuf)> = list_dir(dir)?
        .into_iter()
        .filter_map(|(name, path)| {
            let stem = name.strip_suffix(".depth.png")?;
            let digits = stem.strip_prefix("frame-")?;
            let number = digits.parse::<u64>().ok().filter(|_| digits.bytes().all(|b| b.is_ascii_digit()))?;
            Some((number, stem.to_string(), path))
        })
        .collect();
    frames.sort_by(|a, b| (a.0, &a.1).cmp(&(b.0, &b.1)));
    Ok(frames.into_iter().map(|(_, stem, path)| (stem, path)).collect())
}

/// `(file name, path)` of the entries of `dir` whose names are valid UTF-8.
pub(crate) fn list_dir(dir: &Path) -> Result<Vec<(String, PathBuf)>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut out = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        if let Some(name) = entry.file_name().to_str() {
            out.push((name.to_string(), entry.path()));
        }
    }
    Ok(out)
}

/// The last component of `path` (after resolving `.` and `..`), used as the first part of keys.
pub(crate) fn folder_name(path: &Path) -> String {
    let name = |p: &Path| p.file_name().and_then(|n| n.to_str()).map(str::to_string);
    name(path)
        .or_else(|| std::fs::canonicalize(path).ok().and_then(|p| name(&p)))
        .unwrap_or_else(|| "root".to_string())
}

/// Width and height from a PNG's header, without decoding the image.
pub(crate) fn png_size(path: &Path) -> Result<(u32, u32)> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    let info = decoder
        .read_header_info()
        .map_err(|e| Error::input(path, format!("not a readable PNG ({e})")))?;
    Ok((info.width, info.height))
}

/// The size of the first PNG among `paths` whose header reads; the first error when none does.
pub(crate) fn first_readable_size<P: AsRef<Path>>(paths: impl IntoIterator<Item = P>) -> Result<(u32, u32)> {
    let mut first_err = None;
    for p in paths {
        match png_size(p.as_ref()) {
            Ok(size) => return Ok(size),
            Err(e) => {
                first_err.get_or_insert(e);
            }
        }
    }
    Err(first_err.unwrap_or_else(|| Error::Internal("no depth images to size".into())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sources::depth_png::write_depth_png;
    use nalgebra::{Isometry3, Vector3};

    fn k(w: u32, h: u32) -> Intrinsics {
        Intrinsics::new(585.0, 585.0, 3.5, 2.5, w, h).unwrap()
    }

    /// Writes frame `n` (8×6, every pixel `n + 1000` mm) and, when `pose`, its pose (x = n metres).
    fn frame(dir: &Path, n: u32, pose: bool) {
        write_depth_png(&dir.join(format!("frame-{n:06}.depth.png")), 8, 6, &[n as u16 + 1000; 48]).unwrap();
        if pose {
            let p = Isometry3::new(Vector3::new(n as f64, 0.0, 0.0), Vector3::zeros());
            text::write_pose_file(&dir.join(format!("frame-{n:06}.pose.txt")), &p).unwrap();
        }
    }

    #[test]
    fn flat_folder_lists_sorted_frames_with_keys_size_and_poses() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("7scenes-kitchen");
        std::fs::create_dir(&root).unwrap();
        for (n, pose) in [(100, true), (7, false), (42, true)] {
            frame(&root, n, pose);
        }
        // Unpadded: name order would put it after frame-000100, frame-number order puts it before.
        write_depth_png(&root.join("frame-99.depth.png"), 8, 6, &[1099; 48]).unwrap();
        std::fs::write(root.join("frame-000001.color.png"), b"not a depth").unwrap();
        text::write_intrinsics_file(&root.join("camera-intrinsics.txt"), &k(8, 6)).unwrap();

        let seqs = open(&root).unwrap();
        assert_eq!(seqs.len(), 1);
        let s = &seqs[0];
        assert_eq!(s.name, "7scenes-kitchen");
        let keys: Vec<&str> = s.frames.iter().map(|f| f.key.as_str()).collect();
        assert_eq!(
            keys,
            ["7scenes-kitchen/frame-000007", "7scenes-kitchen/frame-000042", "7scenes-kitchen/frame-99", "7scenes-kitchen/frame-000100"]
        );
        let f = &s.frames[1];
        assert_eq!(f.intrinsics, k(8, 6));
        assert_eq!(f.depth_scale, 1000.0);
        assert_eq!(f.pose, PoseSource::File(root.join("frame-000042.pose.txt")));
        assert_eq!(s.frames[0].pose, PoseSource::None);

        let loaded = f.load().unwrap();
        assert_eq!(loaded.depth.at(3, 2), 1.042);
        assert_eq!(loaded.t_world_from_camera.unwrap().translation.vector.x, 42.0);
    }

    #[test]
    fn seq_folders_give_one_sequence_each_and_fallback_intrinsics_name() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("sun3d-room");
        for (seq, n) in [("seq-02", 5), ("seq-01", 116), ("seq-01", 2)] {
            frame(&root.join(seq), n, true);
        }
        std::fs::create_dir(root.join("seq-03")).unwrap(); // empty: skipped
        text::write_intrinsics_file(&root.join("intrinsics.K.txt"), &k(8, 6)).unwrap();

        let seqs = open(&root).unwrap();
        let names: Vec<&str> = seqs.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["sun3d-room/seq-01", "sun3d-room/seq-02"]);
        let keys: Vec<&str> = seqs[0].frames.iter().map(|f| f.key.as_str()).collect();
        assert_eq!(keys, ["sun3d-room/seq-01/frame-000002", "sun3d-room/seq-01/frame-000116"]);
        assert_eq!(seqs[1].frames[0].key, "sun3d-room/seq-02/frame-000005");
        assert_eq!(seqs[1].frames[0].depth_path, root.join("seq-02/frame-000005.depth.png"));
        assert_eq!(seqs[0].root, root.join("seq-01"));
    }

    #[test]
    fn a_folder_of_scenes_gives_every_scene_in_name_order_with_its_own_intrinsics() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("rgbd");
        frame(&root.join("sun3d-b/seq-01"), 3, true);
        frame(&root.join("7-scenes-a/seq-02"), 1, true);
        frame(&root.join("7-scenes-a/seq-01"), 0, true);
        frame(&root.join("flat-c"), 9, false);
        std::fs::create_dir_all(root.join("notes")).unwrap(); // no frames: skipped
        text::write_intrinsics_file(&root.join("7-scenes-a/camera-intrinsics.txt"), &k(8, 6)).unwrap();
        let k_sun3d = Intrinsics::new(570.0, 570.0, 3.5, 2.5, 8, 6).unwrap();
        text::write_intrinsics_file(&root.join("sun3d-b/camera-intrinsics.txt"), &k_sun3d).unwrap();
        text::write_intrinsics_file(&root.join("flat-c/intrinsics.K.txt"), &k(8, 6)).unwrap();

        let seqs = open(&root).unwrap();
        let names: Vec<&str> = seqs.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["7-scenes-a/seq-01", "7-scenes-a/seq-02", "flat-c", "sun3d-b/seq-01"]);
        assert_eq!(seqs[3].frames[0].key, "sun3d-b/seq-01/frame-000003");
        assert_eq!(seqs[3].frames[0].intrinsics.fx, 570.0);
        assert_eq!(seqs[2].frames[0].pose, PoseSource::None);

        // A scene without intrinsics is an error naming it, not a skipped scene.
        frame(&root.join("d-noK"), 0, true);
        let e = open(&root).unwrap_err().to_string();
        assert!(e.contains("d-noK") && e.contains("camera-intrinsics.txt"), "{e}");
    }

    #[test]
    fn image_size_comes_from_the_png() {
        let tmp = tempfile::tempdir().unwrap();
        write_depth_png(&tmp.path().join("frame-000000.depth.png"), 13, 9, &[1; 117]).unwrap();
        text::write_intrinsics_file(&tmp.path().join("camera-intrinsics.txt"), &k(640, 480)).unwrap();
        let f = &open(tmp.path()).unwrap()[0].frames[0];
        assert_eq!((f.intrinsics.width, f.intrinsics.height), (13, 9));
        assert_eq!(f.intrinsics.fx, 585.0);
    }

    #[test]
    fn missing_intrinsics_and_empty_folder_are_errors_naming_the_root() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("noK");
        frame(&root, 0, true);
        let e = open(&root).unwrap_err().to_string();
        assert!(e.contains("noK") && e.contains("camera-intrinsics.txt") && e.contains("intrinsics.K.txt"), "{e}");

        let empty = tmp.path().join("empty");
        std::fs::create_dir(&empty).unwrap();
        let e = open(&empty).unwrap_err().to_string();
        assert!(e.contains("empty") && e.contains("no frame-"), "{e}");
        let e = open(&tmp.path().join("absent")).unwrap_err().to_string();
        assert!(e.contains("absent"), "{e}");
    }
}
