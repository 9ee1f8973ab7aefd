//! Export a dataset's pairs to the layouts registration trainers read: the PointRegGPT authors' layout
//! (`pointreggpt`), GeoTransformer's 3DMatch pickle + `.pth` clouds (`geotransformer`), or plain PLY pairs
//! (`ply`). Rows stream shard by shard, selected by a SQL `--where` predicate ([`filter`]) and a limit.
//!
//! The training formats take `ok` rows only (others that match the filter are counted as skipped);
//! `ply` writes every matching row, so rejected pairs can be inspected too. Pairs are numbered in export
//! order (unit order), and each export writes `metadata/pairs.tsv` mapping that number to the pair key.

pub mod filter;
pub mod geotransformer;
pub mod npy;
pub mod pickle;
pub mod pth;
pub mod pointreggpt;
pub mod ply;
pub mod rows;

use crate::error::{Error, Result};
use crate::shards::dataset::Dataset;
use crate::shards::row::{PairRow, Status};
pub use filter::Filter;
use std::path::{Path, PathBuf};

/// An export layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// The authors' layout: `data/scene-XXXXXX/sample-00000{0,1}.cloud.ply` in the source frame,
    /// `sample-000001.pose.txt`, `camera-intrinsics.txt`, and `metadata/gt.log`.
    Pointreggpt,
    /// GeoTransformer's 3DMatch layout: `metadata/train.pkl` and `data/train/<scene>/cloud_bin_<i>.pth`
    /// (numpy arrays in torch.save's format; `--cloud-format npy` for `.npy`).
    Geotransformer,
    /// `<pair>/source.ply`, `target.ply` (each in its own camera frame) and `T_target_from_source.txt`.
    Ply,
}

/// What to export and where.
#[derive(Clone, Debug)]
pub struct ExportOptions {
    pub format: Format,
    /// Output folder; must not exist or be empty.
    pub out: PathBuf,
    /// Rows to consider.
    pub filter: Filter,
    /// Write at most this many pairs.
    pub limit: Option<usize>,
    /// `geotransformer` only: the clouds' file format (`.pth` for `torch.load` by default).
    pub cloud_format: geotransformer::CloudFormat,
    /// Draw a progress bar on stderr (when it is a terminal).
    pub progress: bool,
}

/// What an export did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExportReport {
    /// Committed rows read: every row of the shards read (an export stopped by its limit reads on to the
    /// end of that shard).
    pub rows_read: u64,
    /// Rows that matched the filter.
    pub matched: u64,
    /// Pairs written.
    pub written: u64,
    /// Matching rows the format does not take (not `ok`, for the training formats).
    pub skipped: u64,
    /// `pointreggpt` only: pairs listed in `metadata/gt.log` (the official keep rule).
    pub gt_log_lines: Option<u64>,
}

/// One export format: receives the selected rows in order, then finishes its index files.
pub trait PairWriter {
    /// Whether the format takes this row (after the filter).
    fn accepts(&self, row: &PairRow) -> bool;
    /// Writes pair number `index` (0-based, export order).
    fn write(&mut self, index: u64, row: &PairRow) -> Result<()>;
    /// Writes the index files; returns the `gt.log` line count where the format has one.
    fn finish(&mut self) -> Result<Option<u64>>;
}

/// Exports the committed rows of `ds` as `opts` says.
pub fn export(ds: &Dataset, opts: &ExportOptions) -> Result<ExportReport> {
    rows::create_empty_dir(&opts.out)?;
    let mut writer: Box<dyn PairWriter> = match opts.format {
        Format::Pointreggpt => Box::new(pointreggpt::PointRegGptWriter::new(&opts.out)),
        Format::Geotransformer => Box::new(geotransformer::GeoTransformerWriter::new(&opts.out, opts.cloud_format)),
        Format::Ply => Box::new(ply::PlyWriter::new(&opts.out)),
    };
    let bar = crate::runtime::progress::bar(rows::committed_row_count(ds)?, opts.progress, "export");
    let mut report = ExportReport::default();
    report.rows_read = rows::for_each_row(ds, &opts.filter, &bar, |row| {
        report.matched += 1;
        if !writer.accepts(&row) {
            report.skipped += 1;
            return Ok(true);
        }
        if opts.limit.is_some_and(|n| report.written >= n as u64) {
            return Ok(false);
        }
        writer.write(report.written, &row)?;
        report.written += 1;
        Ok(opts.limit.map_or(true, |n| report.written < n as u64))
    })?;
    bar.finish_and_clear();
    report.gt_log_lines = writer.finish()?;
    Ok(report)
}

/// Whether a row is an accepted pair (what the training formats take).
pub fn is_ok(row: &PairRow) -> bool {
    row.status == Status::Ok
}

/// A number as Python's `'%.18e' % v` (numpy's `savetxt` default): `1.000000000000000000e+00`.
pub fn py_sci(v: f64) -> String {
    let s = format!("{v:.18e}");
    match s.split_once('e') {
        Some((m, e)) => {
            let e: i32 = e.parse().expect("rust exponent");
            format!("{m}e{}{:02}", if e < 0 { '-' } else { '+' }, e.abs())
        }
        None => s.to_lowercase(),
    }
}

/// Rows of numbers, space-separated in [`py_sci`] form, one line per row (`np.savetxt` layout).
pub fn matrix_text(values: &[f64], columns: usize) -> String {
    values.chunks(columns).map(|r| r.iter().map(|v| py_sci(*v)).collect::<Vec<_>>().join(" ") + "\n").collect()
}

/// Writes `text` to `path`, creating the parent folder.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

/// The rigid transform of a row, or an error naming the pair.
pub fn row_pose(row: &PairRow) -> Result<nalgebra::Isometry3<f64>> {
    crate::geometry::pose_from_rows(&row.t_target_from_source)
        .map_err(|m| Error::InvalidArgument(format!("pair {}: t_target_from_source: {m}", row.pair_key)))
}

#[cfg(test)]
pub(crate) mod tests_support {
    use crate::shards::row::PairRow;

    /// An `ok` 4×4 row of frame `s/frame-000000` with empty clouds and the identity pose, for unit tests.
    pub fn empty_row() -> PairRow {
        PairRow {
            pair_key: "s/frame-000000#0".into(),
            scene: "s".into(),
            frame_key: "s/frame-000000".into(),
            width: 4,
            height: 4,
            source_intrinsics: [2.0; 4],
            target_intrinsics: [2.0; 4],
            pose_draws: 1,
            ..PairRow::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_formatted_as_numpy_savetxt() {
        assert_eq!(py_sci(1.0), "1.000000000000000000e+00");
        assert_eq!(py_sci(-0.0125), "-1.250000000000000069e-02");
        assert_eq!(py_sci(123456.0), "1.234560000000000000e+05");
        assert_eq!(matrix_text(&[1.0, 0.0, 0.0, 1.0], 2), "1.000000000000000000e+00 0.000000000000000000e+00\n0.000000000000000000e+00 1.000000000000000000e+00\n");
    }
}
