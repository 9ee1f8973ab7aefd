//! The official 3DMatch ground-truth files. `gt.log`: per pair a line `i j n` (fragment indices, fragment
//! count) and the 4×4 that maps fragment j into fragment i (`p_i = T·p_j`). `gt.info`: the same header
//! and the 6×6 information matrix. `gt_overlap.log`: `i j overlap` per line (ours; GeoTransformer's
//! metadata has the same name for the same idea).

use crate::error::{Error, Result};
use crate::geometry::{pose_from_rows, pose_to_rows};
use nalgebra::{Isometry3, Matrix6};
use std::fmt::Write as _;
use std::path::Path;

/// One pair of a `gt.log`: target fragment `i`, source fragment `j`, fragment count, `t_i_from_j`.
#[derive(Clone, Debug, PartialEq)]
pub struct GtPair {
    pub i: usize,
    pub j: usize,
    pub n: usize,
    pub t_i_from_j: Isometry3<f64>,
}

fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| Error::io(path, e))
}

/// Records of a header line `i j n` followed by `rows` lines of `cols` numbers.
fn records(path: &Path, rows: usize, cols: usize) -> Result<Vec<((usize, usize, usize), Vec<f64>)>> {
    let text = read_text(path)?;
    let lines: Vec<(usize, &str)> = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()).collect();
    if lines.len() % (rows + 1) != 0 {
        return Err(Error::input(
            path,
            format!("{} non-empty lines is not a whole number of {}-line records", lines.len(), rows + 1),
        ));
    }
    let mut out = Vec::new();
    for rec in lines.chunks(rows + 1) {
        let (ln, head) = rec[0];
        let h: Vec<usize> = head
            .split_whitespace()
            .map(str::parse)
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| Error::input(path, format!("line {}: `{head}` is not `i j n`", ln + 1)))?;
        let [i, j, n] = h[..] else {
            return Err(Error::input(path, format!("line {}: `{head}` is not `i j n`", ln + 1)));
        };
        let mut values = Vec::with_capacity(rows * cols);
        for &(ln, l) in &rec[1..] {
            let v: Vec<f64> = l
                .split_whitespace()
                .map(str::parse)
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| Error::input(path, format!("line {}: `{l}` is not {cols} numbers", ln + 1)))?;
            if v.len() != cols || v.iter().any(|x| !x.is_finite()) {
                return Err(Error::input(path, format!("line {}: expected {cols} finite numbers, got `{l}`", ln + 1)));
            }
            values.extend(v);
        }
        out.push(((i, j, n), values));
    }
    Ok(out)
}

/// Reads a `gt.log`; errors name the file and line.
pub fn read_gt_log(path: &Path) -> Result<Vec<GtPair>> {
    records(path, 4, 4)?
        .into_iter()
        .map(|((i, j, n), v)| {
            let rows: [f64; 16] = v.try_into().expect("16 values");
            let t = pose_from_rows(&rows).map_err(|m| Error::input(path, format!("pair {i} {j}: {m}")))?;
            Ok(GtPair { i, j, n, t_i_from_j: t })
        })
        .collect()
}

/// Reads a `gt.info`: per (i, j) its 6×6 information matrix.
pub fn read_gt_info(path: &Path) -> Result<Vec<((usize, usize), Matrix6<f64>)>> {
    Ok(records(path, 6, 6)?.into_iter().map(|((i, j, _), v)| ((i, j), Matrix6::from_row_slice(&v))).collect())
}

/// Reads a `gt_overlap.log` (`i j overlap` per line).
pub fn read_gt_overlap(path: &Path) -> Result<Vec<((usize, usize), f64)>> {
    let text = read_text(path)?;
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(ln, l)| {
            let w: Vec<&str> = l.split_whitespace().collect();
            let parsed = match w[..] {
                [i, j, o] => i.parse::<usize>().ok().zip(j.parse::<usize>().ok()).zip(o.parse::<f64>().ok()),
                _ => None,
            };
            parsed
                .map(|(ij, o)| (ij, o))
                .ok_or_else(|| Error::input(path, format!("line {}: `{l}` is not `i j overlap`", ln + 1)))
        })
        .collect()
}

fn write(path: &Path, text: String) -> Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

/// Writes a `gt.log` (values with 17 significant digits, so they read back exactly).
pub fn write_gt_log(path: &Path, pairs: &[GtPair]) -> Result<()> {
    let mut s = String::new();
    for p in pairs {
        let _ = writeln!(s, "{}\t{}\t{}", p.i, p.j, p.n);
        for row in pose_to_rows(&p.t_i_from_j).chunks(4) {
            let _ = writeln!(s, "{}", row.iter().map(|x| format!("{x:.17e}")).collect::<Vec<_>>().join("\t"));
        }
    }
    write(path, s)
}

/// Writes a `gt.info`: per pair its header `i j n` and the 6×6 matrix.
pub fn write_gt_info(path: &Path, pairs: &[(GtPair, Matrix6<f64>)]) -> Result<()> {
    let mut s = String::new();
    for (p, info) in pairs {
        let _ = writeln!(s, "{}\t{}\t{}", p.i, p.j, p.n);
        for r in 0..6 {
            let _ = writeln!(s, "{}", (0..6).map(|c| format!("{:.17e}", info[(r, c)])).collect::<Vec<_>>().join("\t"));
        }
    }
    write(path, s)
}

/// Writes a `gt_overlap.log`.
pub fn write_gt_overlap(path: &Path, pairs: &[((usize, usize), f64)]) -> Result<()> {
    let mut s = String::new();
    for ((i, j), o) in pairs {
        let _ = writeln!(s, "{i}\t{j}\t{o:.6}");
    }
    write(path, s)
}
