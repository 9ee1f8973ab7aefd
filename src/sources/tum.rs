//! The TUM RGB-D layout: `depth.txt` listing depth PNGs (5000 units per metre) and `groundtruth.txt`
//! holding camera-to-world poses, associated to depth frames by nearest timestamp.

use super::threedmatch::folder_name;
use super::{FrameRef, PoseSource, Sequence};
use crate::error::{Error, Result};
use crate::geometry::Intrinsics;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::path::Path;

/// Raw depth units per metre of TUM depth PNGs.
pub const DEPTH_SCALE: f32 = 5000.0;

/// Largest timestamp difference (seconds) at which a ground-truth pose is associated to a depth frame
/// (the tolerance of TUM's `associate.py`).
pub const MAX_TIME_DIFFERENCE: f64 = 0.02;

/// The intrinsics used when none are given: the TUM ROS default for registered depth
/// (fx = fy = 525, cx = 319.5, cy = 239.5, 640×480). The TUM sequences' depth images are registered
/// to the colour camera with these values, so they apply to all three Kinects (freiburg1/2/3).
pub fn default_intrinsics() -> Intrinsics {
    Intrinsics::new(525.0, 525.0, 319.5, 239.5, 640, 480).expect("valid constant intrinsics")
}

/// Opens the TUM sequence in `root`. Frames follow `depth.txt` sorted by timestamp; keys are
/// `<root name>/<timestamp as written>`. Each frame gets the `groundtruth.txt` pose nearest in time
/// when it is within [`MAX_TIME_DIFFERENCE`] ([`PoseSource::Known`]), else [`PoseSource::None`]; a
/// sequence without `groundtruth.txt` has no poses. `intrinsics` defaults to [`default_intrinsics`].
/// Malformed lines fail with the file and line number; so do duplicate depth timestamps.
pub fn open(root: &Path, intrinsics: Option<Intrinsics>) -> Result<Sequence> {
    let intrinsics = intrinsics.unwrap_or_else(default_intrinsics);
    let name = folder_name(root);
    let depth_txt = root.join("depth.txt");
    let mut depth = Vec::new();
    for (line_no, fields) in data_lines(&depth_txt)? {
        let bad = |m: String| Error::input(&depth_txt, format!("line {line_no}: {m}"));
        if fields.len() != 2 {
            return Err(bad(format!("expected `timestamp path`, found {} fields", fields.len())));
        }
        let t = parse_time(&fields[0]).map_err(bad)?;
        depth.push((t, fields[0].clone(), fields[1].clone(), line_no));
    }
    if depth.is_empty() {
        return Err(Error::input(&depth_txt, "lists no depth images"));
    }
    depth.sort_by(|a, b| a.0.total_cmp(&b.0));
    if let Some(w) = depth.windows(2).find(|w| w[0].0 == w[1].0) {
        return Err(Error::input(&depth_txt, format!("line {}: timestamp {} is listed twice", w[1].3, w[1].1)));
    }

    let gt_path = root.join("groundtruth.txt");
    let poses = if gt_path.is_file() { read_groundtruth(&gt_path)? } else { Vec::new() };
    let frames = depth
        .into_iter()
        .map(|(t, stamp, rel, _)| FrameRef {
            key: format!("{name}/{stamp}"),
            depth_path: root.join(rel),
            depth_scale: DEPTH_SCALE,
            intrinsics,
            pose: nearest_pose(&poses, t).map_or(PoseSource::None, PoseSource::Known),
        })
        .collect();
    Ok(Sequence { name, root: root.to_path_buf(), frames })
}

/// Reads `groundtruth.txt` (`timestamp tx ty tz qx qy qz qw`, camera-to-world) sorted by time.
pub fn read_groundtruth(path: &Path) -> Result<Vec<(f64, Isometry3<f64>)>> {
    let mut poses = Vec::new();
    for (line_no, fields) in data_lines(path)? {
        let bad = |m: String| Error::input(path, format!("line {line_no}: {m}"));
        if fields.len() != 8 {
            return Err(bad(format!("expected `timestamp tx ty tz qx qy qz qw`, found {} fields", fields.len())));
        }
        let t = parse_time(&fields[0]).map_err(bad)?;
        let mut v = [0.0; 7];
        for (slot, tok) in v.iter_mut().zip(&fields[1..]) {
            *slot = tok.parse::<f64>().ok().filter(|x| x.is_finite()).ok_or_else(|| bad(format!("`{tok}` is not a finite number")))?;
        }
        let q = Quaternion::new(v[6], v[3], v[4], v[5]);
        if (q.norm() - 1.0).abs() > 0.01 {
            return Err(bad(format!("quaternion norm is {:.6}, expected 1", q.norm())));
        }
        let pose = Isometry3::from_parts(Translation3::new(v[0], v[1], v[2]), UnitQuaternion::from_quaternion(q));
        poses.push((t, pose));
    }
    poses.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(poses)
}

/// The pose of `poses` (sorted by time) nearest to `t`, if within [`MAX_TIME_DIFFERENCE`]; on a tie
/// the earlier one.
fn nearest_pose(poses: &[(f64, Isometry3<f64>)], t: f64) -> Option<Isometry3<f64>> {
    let i = poses.partition_point(|(pt, _)| *pt < t);
    let candidates = [i.checked_sub(1), Some(i)];
    candidates
        .into_iter()
        .flatten()
        .filter_map(|j| poses.get(j))
        .map(|(pt, p)| ((pt - t).abs(), p))
        .filter(|(dt, _)| *dt <= MAX_TIME_DIFFERENCE)
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, p)| *p)
}

fn parse_time(tok: &str) -> std::result::Result<f64, String> {
    tok.parse::<f64>().ok().filter(|t| t.is_finite()).ok_or_else(|| format!("`{tok}` is not a timestamp"))
}

/// `(1-based line number, whitespace-separated fields)` of the non-blank, non-`#` lines of `path`.
fn data_lines(path: &Path) -> Result<Vec<(usize, Vec<String>)>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    Ok(text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
        .map(|(i, l)| (i, l.split_whitespace().map(str::to_string).collect()))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sources::depth_png::write_depth_png;
    use nalgebra::Vector3;

    const HEADER: &str = "# depth maps\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n# timestamp filename\n";

    fn fixture(depth_txt: &str, groundtruth: Option<&str>) -> tempfile::TempDir {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("rgbd_dataset_freiburg1_xyz");
        std::fs::create_dir(&root).unwrap();
        std::fs::write(root.join("depth.txt"), depth_txt).unwrap();
        if let Some(g) = groundtruth {
            std::fs::write(root.join("groundtruth.txt"), g).unwrap();
        }
        tmp
    }

    fn root(tmp: &tempfile::TempDir) -> std::path::PathBuf {
        tmp.path().join("rgbd_dataset_freiburg1_xyz")
    }

    #[test]
    fn lists_frames_and_associates_the_nearest_pose() {
        let depth = format!(
            "{HEADER}1305031102.160407 depth/1305031102.160407.png\n\n1305031102.194330 depth/1305031102.194330.png\n1305031102.300000 depth/1305031102.300000.png\n"
        );
        // For 102.160407 the poses at 102.1475 (12.9 ms before) and 102.1675 (7.1 ms after) are both
        // within 20 ms: the later, nearer one (x = 2) must win although it comes second. For
        // 102.194330 the nearest is 102.1975 (x = 3). Nothing lies within 20 ms of 102.300000.
        let gt = "# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n\
                  1305031102.1475 1.0 0.0 0.0 0 0 0 1\n\
                  1305031102.1675 2.0 0.0 0.0 0 0 0.7071068 0.7071068\n\
                  1305031102.1975 3.0 0.5 -1.0 0 0 0 1\n\
                  1305031102.2750 4.0 0.0 0.0 0 0 0 1\n";
        let tmp = fixture(&depth, Some(gt));
        let r = root(&tmp);
        let k = Intrinsics::new(517.3, 516.5, 318.6, 255.3, 640, 480).unwrap();
        let s = open(&r, Some(k)).unwrap();
        assert_eq!(s.name, "rgbd_dataset_freiburg1_xyz");
        let keys: Vec<&str> = s.frames.iter().map(|f| f.key.as_str()).collect();
        assert_eq!(
            keys,
            ["rgbd_dataset_freiburg1_xyz/1305031102.160407", "rgbd_dataset_freiburg1_xyz/1305031102.194330", "rgbd_dataset_freiburg1_xyz/1305031102.300000"]
        );
        assert_eq!(s.frames[0].depth_path, r.join("depth/1305031102.160407.png"));
        assert_eq!(s.frames[0].depth_scale, 5000.0);
        assert_eq!(s.frames[0].intrinsics, k);

        let PoseSource::Known(p0) = &s.frames[0].pose else { panic!("frame 0 has no pose") };
        assert_eq!(p0.translation.vector, Vector3::new(2.0, 0.0, 0.0));
        // 90° about z (qz = qw = √½): the camera x axis maps to world y.
        assert!((p0.rotation * Vector3::x() - Vector3::y()).norm() < 1e-6);
        let PoseSource::Known(p1) = &s.frames[1].pose else { panic!("frame 1 has no pose") };
        assert_eq!(p1.translation.vector, Vector3::new(3.0, 0.5, -1.0));
        assert_eq!(s.frames[2].pose, PoseSource::None);
    }

    #[test]
    fn default_intrinsics_no_groundtruth_and_loading_uses_scale_5000() {
        let tmp = fixture("2.5 depth/b.png\n1.0 depth/a.png\n", None);
        let r = root(&tmp);
        write_depth_png(&r.join("depth/a.png"), 640, 480, &vec![5000u16; 640 * 480]).unwrap();
        let s = open(&r, None).unwrap();
        assert_eq!(s.frames[0].key, "rgbd_dataset_freiburg1_xyz/1.0"); // sorted by time
        assert_eq!(s.frames[1].key, "rgbd_dataset_freiburg1_xyz/2.5");
        let k = s.frames[0].intrinsics;
        assert_eq!((k.fx, k.fy, k.cx, k.cy, k.width, k.height), (525.0, 525.0, 319.5, 239.5, 640, 480));
        assert!(s.frames.iter().all(|f| f.pose == PoseSource::None));
        let f = s.frames[0].load().unwrap();
        assert_eq!(f.depth.at(100, 100), 1.0);
        assert!(f.t_world_from_camera.is_none());
    }

    #[test]
    fn malformed_lines_name_the_file_and_line() {
        let tmp = fixture(&format!("{HEADER}1.0 depth/a.png\n1.1depth/b.png\n"), None);
        let e = open(&root(&tmp), None).unwrap_err().to_string();
        assert!(e.contains("depth.txt") && e.contains("line 5") && e.contains("found 1 fields"), "{e}");

        let tmp = fixture("abc depth/a.png\n", None);
        let e = open(&root(&tmp), None).unwrap_err().to_string();
        assert!(e.contains("depth.txt") && e.contains("line 1") && e.contains("`abc` is not a timestamp"), "{e}");

        let tmp = fixture("1.0 depth/a.png\n", Some("# c\n1.0 0 0 0 0 0 0 1\n1.1 0 0 nan 0 0 0 1\n"));
        let e = open(&root(&tmp), None).unwrap_err().to_string();
        assert!(e.contains("groundtruth.txt") && e.contains("line 3") && e.contains("`nan`"), "{e}");

        let tmp = fixture("1.0 depth/a.png\n", Some("1.0 0 0 0 0 0 0 2\n"));
        let e = open(&root(&tmp), None).unwrap_err().to_string();
        assert!(e.contains("groundtruth.txt") && e.contains("line 1") && e.contains("quaternion norm is 2"), "{e}");

        let tmp = fixture("1.0 depth/a.png\n1.00 depth/b.png\n", None);
        let e = open(&root(&tmp), None).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("listed twice"), "{e}");

        let tmp = fixture("# only a comment\n", None);
        assert!(open(&root(&tmp), None).unwrap_err().to_string().contains("lists no depth images"));
        let e = open(&tmp.path().join("missing"), None).unwrap_err().to_string();
        assert!(e.contains("missing") && e.contains("depth.txt"), "{e}");
    }
}
