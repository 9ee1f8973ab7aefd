//! Pictures of a dataset: one PNG montage per pair ([`montage`]) and the statistics plot ([`stats`]),
//! drawn with a small RGB rasteriser ([`canvas`]), a 5×7 bitmap font ([`font`]) and Turbo
//! ([`colormap`]); no imaging crate.

pub mod canvas;
pub mod colormap;
pub mod font;
pub mod montage;
pub mod stats;

use crate::error::{Error, Result};
use crate::export::rows::{committed_row_count, for_each_row, unique_name};
use crate::runtime::progress::bar as progress_bar;
use crate::export::Filter;
use crate::shards::dataset::Dataset;
pub use montage::{montage_size, render_pair};
pub use stats::Stats;
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// Which pairs to draw and where.
#[derive(Clone, Debug)]
pub struct PreviewOptions {
    /// Output folder (created; existing files of the same name are replaced).
    pub out: PathBuf,
    pub filter: Filter,
    /// At most this many montages.
    pub limit: usize,
    pub progress: bool,
}

/// Writes `<out>/<pair key, sanitized>.png` for the first `limit` rows matching the filter (unit
/// order); returns the files written. Only the matching rows are decoded.
pub fn write_previews(ds: &Dataset, opts: &PreviewOptions) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(&opts.out).map_err(|e| Error::io(&opts.out, e))?;
    let mut used = HashSet::new();
    let mut files = Vec::new();
    if opts.limit == 0 {
        return Ok(files);
    }
    let bar = progress_bar(committed_row_count(ds)?, opts.progress, "preview");
    for_each_row(ds, &opts.filter, &bar, |row| {
        let path = opts.out.join(format!("{}.png", unique_name(&mut used, &row.pair_key, row.unit_index)));
        render_pair(&row)?.write_png(&path)?;
        files.push(path);
        Ok(files.len() < opts.limit)
    })?;
    bar.finish_and_clear();
    Ok(files)
}

/// Counts the rows of `ds` matching `filter` with SQL aggregates over the committed shards
/// ([`stats::counts_sql`], [`stats::paths_sql`]): no row is decoded. Datasets older than the scene
/// (schema before `pairs/3`) have every row on the single-map path.
pub fn collect_stats(ds: &Dataset, filter: &Filter) -> Result<Stats> {
    let batches = crate::query::run_query_on(ds, &stats::counts_sql(filter.sql()))?;
    let mut stats = Stats::from_counts(&batches)?;
    if ds.header().schema_version == crate::shards::SCHEMA_VERSION {
        stats.add_paths(&crate::query::run_query_on(ds, &stats::paths_sql(filter.sql()))?)?;
    } else {
        stats.per_path.insert(stats::PATHS[1].to_string(), stats.total.by_status);
    }
    Ok(stats)
}

/// Writes `stats.txt` and `stats.png` into `out` (created); returns the text.
pub fn write_stats(stats: &Stats, out: &Path, per_scene: bool) -> Result<String> {
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let text = stats.table(per_scene);
    let txt = out.join("stats.txt");
    std::fs::write(&txt, &text).map_err(|e| Error::io(&txt, e))?;
    stats.plot().write_png(&out.join("stats.png"))?;
    Ok(text)
}
