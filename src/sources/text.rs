//! Small text files of the 3DMatch layout: 4×4 pose matrices and 3×3 (or 4×4) intrinsics.

use crate::error::{Error, Result};
use crate::geometry::{pose_from_rows, pose_to_rows, Intrinsics};
use nalgebra::Isometry3;
use std::path::Path;

/// Whitespace-separated numbers of a text file (tabs, spaces, newlines; `nan`/`inf` parse).
pub fn read_numbers(path: &Path) -> Result<Vec<f64>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    text.split_whitespace()
        .map(|tok| tok.parse::<f64>().map_err(|_| Error::input(path, format!("`{tok}` is not a number"))))
        .collect()
}

/// Reads a row-major 4×4 camera-to-world pose; rejects other sizes, non-finite values and
/// non-rigid matrices.
pub fn read_pose_file(path: &Path) -> Result<Isometry3<f64>> {
    let v = read_numbers(path)?;
    if v.len() != 16 {
        return Err(Error::input(path, format!("pose file must hold 16 numbers (4x4), found {}", v.len())));
    }
    let rows: [f64; 16] = v.try_into().expect("16 numbers");
    pose_from_rows(&rows).map_err(|m| Error::input(path, m))
}

/// Writes a pose as four lines of four numbers (the 3DMatch `.pose.txt` format).
pub fn write_pose_file(path: &Path, pose: &Isometry3<f64>) -> Result<()> {
    let rows = pose_to_rows(pose);
    let text: String = rows
        .chunks(4)
        .map(|r| r.iter().map(|v| format!("{v:.18e}")).collect::<Vec<_>>().join(" ") + "\n")
        .collect();
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

/// Reads a 3×3 camera matrix (or the 4×4 ScanNet form, whose top-left 3×3 is used) for an image of
/// `width`×`height`.
pub fn read_intrinsics_file(path: &Path, width: u32, height: u32) -> Result<Intrinsics> {
    let v = read_numbers(path)?;
    let (fx, cx, fy, cy) = match v.len() {
        9 => (v[0], v[2], v[4], v[5]),
        16 => (v[0], v[2], v[5], v[6]),
        n => return Err(Error::input(path, format!("intrinsics file must hold a 3x3 or 4x4 matrix, found {n} numbers"))),
    };
    Intrinsics::new(fx, fy, cx, cy, width, height).map_err(|e| Error::input(path, e.to_string()))
}

/// Writes a 3×3 camera matrix (the 3DMatch `camera-intrinsics.txt` format).
pub fn write_intrinsics_file(path: &Path, k: &Intrinsics) -> Result<()> {
    let m = k.matrix();
    let text: String = (0..3)
        .map(|r| (0..3).map(|c| format!("{:.18e}", m[(r, c)])).collect::<Vec<_>>().join(" ") + "\n")
        .collect();
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn pose_and_intrinsics_round_trip_and_errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("frame-000000.pose.txt");
        let pose = Isometry3::new(Vector3::new(0.1, -2.0, 3.0), Vector3::new(0.3, 0.2, -0.1));
        write_pose_file(&p, &pose).unwrap();
        let back = read_pose_file(&p).unwrap();
        assert!((back.to_homogeneous() - pose.to_homogeneous()).abs().max() < 1e-12);

        let k = Intrinsics::new(585.0, 586.0, 320.0, 240.0, 640, 480).unwrap();
        let kp = dir.path().join("camera-intrinsics.txt");
        write_intrinsics_file(&kp, &k).unwrap();
        assert_eq!(read_intrinsics_file(&kp, 640, 480).unwrap(), k);

        std::fs::write(&p, "1 0 0 0\n0 1 0 0\n0 0 1 0\n").unwrap();
        let e = read_pose_file(&p).unwrap_err().to_string();
        assert!(e.contains("frame-000000.pose.txt") && e.contains("16 numbers"), "{e}");
        std::fs::write(&p, "nan 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1").unwrap();
        assert!(read_pose_file(&p).unwrap_err().to_string().contains("non-finite"));
        std::fs::write(&p, "1 0 0 0 0 1 x 0 0 0 1 0 0 0 0 1").unwrap();
        assert!(read_pose_file(&p).unwrap_err().to_string().contains("`x` is not a number"));
        let missing = dir.path().join("missing.txt");
        assert!(read_pose_file(&missing).unwrap_err().to_string().contains("missing.txt"));
    }
}
