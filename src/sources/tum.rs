//! The TUM RGB-D layout: `depth.txt` listing depth PNGs (5000 units per metre) and `groundtruth.txt`
//! holding camera-to-world poses from motion capture, associated to depth frames by timestamp: the
//! sample at the frame's time, or the pose interpolated between the two samples around it
//! ([`associate`]).

use super::threedmatch::folder_name;
use super::{FrameRef, PoseCounts, PoseSource, Sequence};
use crate::error::{Error, Result};
use crate::geometry::Intrinsics;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::path::Path;

/// Raw depth units per metre of TUM depth PNGs.
pub const DEPTH_SCALE: f32 = 5000.0;

/// A depth timestamp within this of a ground-truth sample takes that sample's pose as it is, seconds
/// (TUM writes ground-truth times to 0.1 ms).
pub const EXACT_TIME: f64 = 1e-4;

/// A depth frame between two consecutive ground-truth samples at most this far apart gets the pose
/// interpolated between them (position linearly, rotation by slerp along the shorter arc), seconds. Both
/// samples then lie within this of the frame's timestamp. The motion capture runs at 100 Hz, so up to
/// nine missing samples are bridged; a frame in a longer gap, or before the first or after the last
/// sample, has no pose.
pub const MAX_INTERPOLATION_GAP: f64 = 0.1;

/// The intrinsics used when none are given: the TUM ROS default for registered depth
/// (fx = fy = 525, cx = 319.5, cy = 239.5, 640×480). The TUM sequences' depth images are registered
/// to the colour camera with these values, so they apply to all three Kinects (freiburg1/2/3).
pub fn default_intrinsics() -> Intrinsics {
    Intrinsics::new(525.0, 525.0, 319.5, 239.5, 640, 480).expect("valid constant intrinsics")
}

/// Opens the TUM sequence in `root`. Frames follow `depth.txt` sorted by timestamp; keys are
/// `<root name>/<timestamp as written>`. Each frame gets its pose from `groundtruth.txt` by
/// [`associate`] ([`PoseSource::Known`]), else [`PoseSource::None`]; a sequence without
/// `groundtruth.txt` has no poses. The counts go to [`Sequence::poses`]. `intrinsics` defaults to
/// [`default_intrinsics`].
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
    let mut counts = PoseCounts::default();
    let frames = depth
        .into_iter()
        .map(|(t, stamp, rel, _)| {
            let pose = match associate(&poses, t) {
                Association::Exact(p) => {
                    counts.exact += 1;
                    PoseSource::Known(p)
                }
                Association::Interpolated(p) => {
                    counts.interpolated += 1;
                    PoseSource::Known(p)
                }
                Association::None => {
                    counts.without += 1;
                    PoseSource::None
                }
            };
            FrameRef { key: format!("{name}/{stamp}"), depth_path: root.join(rel), depth_scale: DEPTH_SCALE, intrinsics, pose }
        })
        .collect();
    Ok(Sequence { name, root: root.to_path_buf(), frames, poses: counts })
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

/// How a depth timestamp got its pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Association {
    /// A sample within [`EXACT_TIME`].
    Exact(Isometry3<f64>),
    /// Between two samples at most [`MAX_INTERPOLATION_GAP`] apart.
    Interpolated(Isometry3<f64>),
    /// No sample at the time, and none on one side or the gap around it too long.
    None,
}

/// The pose of time `t` from `poses` (sorted by time): the nearest sample if within [`EXACT_TIME`]
/// (on a tie the earlier), else the interpolation between the samples just before and just after `t`
/// when they are at most [`MAX_INTERPOLATION_GAP`] apart.
pub fn associate(poses: &[(f64, Isometry3<f64>)], t: f64) -> Association {
    let i = poses.partition_point(|(pt, _)| *pt < t);
    let exact = [i.checked_sub(1), Some(i)]
        .into_iter()
        .flatten()
        .filter_map(|j| poses.get(j))
        .map(|(pt, p)| ((pt - t).abs(), p))
        .filter(|(dt, _)| *dt <= EXACT_TIME)
        .min_by(|a, b| a.0.total_cmp(&b.0));
    if let Some((_, p)) = exact {
        return Association::Exact(*p);
    }
    match (i.checked_sub(1).and_then(|j| poses.get(j)), poses.get(i)) {
        (Some((t0, p0)), Some((t1, p1))) if t1 - t0 <= MAX_INTERPOLATION_GAP => Association::Interpolated(interpolate(p0, p1, (t - t0) / (t1 - t0))),
        _ => Association::None,
    }
}

/// The pose a fraction `s` of the way from `a` to `b`: translation linearly, rotation by slerp along the
/// shorter arc (`q` and `−q` are the same rotation; the one nearer `a`'s is taken).
pub fn interpolate(a: &Isometry3<f64>, b: &Isometry3<f64>, s: f64) -> Isometry3<f64> {
    let qa = a.rotation;
    let qb = if qa.coords.dot(&b.rotation.coords) < 0.0 { UnitQuaternion::new_unchecked(-b.rotation.into_inner()) } else { b.rotation };
    let translation = a.translation.vector.lerp(&b.translation.vector, s);
    Isometry3::from_parts(Translation3::from(translation), qa.slerp(&qb, s))
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
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

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
    fn lists_frames_with_exact_interpolated_and_missing_poses() {
        let depth = format!(
            "{HEADER}1305031102.160407 depth/1305031102.160407.png\n\n1305031102.197500 depth/1305031102.197500.png\n1305031102.300000 depth/1305031102.300000.png\n"
        );
        // 102.160407 lies between 102.1475 (x = 1, identity) and 102.1675 (x = 2, 90° about z), 20 ms
        // apart: interpolated at s = 0.64535. 102.1975 is a sample: exact (x = 3). 102.3 lies after the
        // last sample: no pose.
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
            ["rgbd_dataset_freiburg1_xyz/1305031102.160407", "rgbd_dataset_freiburg1_xyz/1305031102.197500", "rgbd_dataset_freiburg1_xyz/1305031102.300000"]
        );
        assert_eq!(s.frames[0].depth_path, r.join("depth/1305031102.160407.png"));
        assert_eq!(s.frames[0].depth_scale, 5000.0);
        assert_eq!(s.frames[0].intrinsics, k);
        assert_eq!(s.poses, PoseCounts { exact: 1, interpolated: 1, without: 1 });

        let PoseSource::Known(p0) = &s.frames[0].pose else { panic!("frame 0 has no pose") };
        let f = (0.160407 - 0.1475) / 0.02;
        assert!((p0.translation.vector - Vector3::new(1.0 + f, 0.0, 0.0)).norm() < 1e-5, "{p0:?}");
        assert!((p0.rotation.angle() - f * std::f64::consts::FRAC_PI_2).abs() < 1e-5);
        let PoseSource::Known(p1) = &s.frames[1].pose else { panic!("frame 1 has no pose") };
        assert_eq!(p1.translation.vector, Vector3::new(3.0, 0.5, -1.0));
        assert_eq!(s.frames[2].pose, PoseSource::None);
    }

    /// The analytic trajectory: position `(t, 2t, −t)` m, rotation `ω·t` about a fixed tilted axis
    /// (slerp between two samples of a constant-rate rotation about a fixed axis is exact). Samples every
    /// 10 ms over 1 s, some stored with the quaternion's sign flipped (`−q` is the same rotation); one
    /// sample missing at 0.30 s (a 20 ms gap: bridged) and none from 0.505 to 0.695 s (a 200 ms gap:
    /// longer than the bound).
    #[test]
    fn interpolation_matches_an_analytic_trajectory_whatever_the_quaternion_signs() {
        let axis = nalgebra::Unit::new_normalize(Vector3::new(0.3, -1.0, 0.5));
        let omega = 2.0; // rad/s
        let truth = |t: f64| {
            Isometry3::from_parts(Translation3::new(t, 2.0 * t, -t), UnitQuaternion::from_axis_angle(&axis, omega * t))
        };
        let mut gt = String::from("# timestamp tx ty tz qx qy qz qw\n");
        for n in 0..=100 {
            let t = n as f64 * 0.01;
            if n == 30 || (51..=69).contains(&n) {
                continue;
            }
            let p = truth(t);
            let q = p.rotation.into_inner();
            let sign = if n % 3 == 0 { -1.0 } else { 1.0 };
            let v = p.translation.vector;
            gt.push_str(&format!("{t:.4} {} {} {} {} {} {} {}\n", v.x, v.y, v.z, sign * q.i, sign * q.j, sign * q.k, sign * q.w));
        }
        let stamps = [0.1234, 0.2955, 0.3020, 0.45, 0.5100, 0.5975, 0.7012, 0.98, 1.2];
        let depth: String = stamps.iter().map(|t| format!("{t:.6} depth/{t:.6}.png\n")).collect();
        let tmp = fixture(&depth, Some(&gt));
        let s = open(&root(&tmp), None).unwrap();
        for (f, &t) in s.frames.iter().zip(&stamps) {
            let expect_pose = !(0.5 < t && t < 0.7) && t <= 1.0;
            match (&f.pose, expect_pose) {
                (PoseSource::Known(p), true) => {
                    let want = truth(t);
                    assert!((p.translation.vector - want.translation.vector).norm() < 1e-9, "t = {t}: {p:?}");
                    assert!(p.rotation.angle_to(&want.rotation) < 1e-9, "t = {t}: rotation off by {}", p.rotation.angle_to(&want.rotation));
                }
                (PoseSource::None, false) => {}
                (got, _) => panic!("t = {t}: expected a pose: {expect_pose}, got {got:?}"),
            }
        }
        // 0.45 and 0.98 are samples (exact); 0.51 and 0.5975 lie in the 200 ms gap, 1.2 after the last sample.
        assert_eq!(s.poses, PoseCounts { exact: 2, interpolated: 4, without: 3 });
    }

    #[test]
    fn interpolation_takes_the_shorter_arc() {
        let a = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, 0.1));
        let b = Isometry3::from_parts(Translation3::new(1.0, 0.0, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3));
        let flipped = Isometry3::from_parts(b.translation, UnitQuaternion::new_unchecked(-b.rotation.into_inner()));
        for other in [b, flipped] {
            let m = interpolate(&a, &other, 0.5);
            assert!((m.rotation.euler_angles().2 - 0.2).abs() < 1e-12, "{:?}", m.rotation.euler_angles());
            assert!((m.translation.x - 0.5).abs() < 1e-12);
        }
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
