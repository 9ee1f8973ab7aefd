//! Streaming the committed rows a `--where` filter selects, shard by shard (so memory holds one shard), in
//! unit order, and the file naming the export and preview commands share.

use crate::error::{Error, Result};
use crate::shards::dataset::{Dataset, PAIRS_TABLE};
use crate::shards::pairs::batch_to_pairs;
use crate::shards::pairs_versions::to_current;
use crate::shards::row::PairRow;
use super::Filter;
use indicatif::ProgressBar;

/// Rows of the committed `pairs` shards, from their manifest entries.
pub fn committed_row_count(ds: &Dataset) -> Result<u64> {
    Ok(ds.committed(PAIRS_TABLE)?.values().map(|e| e.rows).sum())
}

/// Calls `f` with every committed row that `filter` selects, in `unit_index` order (shards hold
/// consecutive unit ranges), reading one shard at a time: the predicate runs on the shard's batches and
/// only the selected rows are decoded into [`PairRow`]s. Stops early when `f` returns `Ok(false)`.
/// `bar` advances by each shard's rows; returns the rows read (every row of the shards read).
pub fn for_each_row(ds: &Dataset, filter: &Filter, bar: &ProgressBar, mut f: impl FnMut(PairRow) -> Result<bool>) -> Result<u64> {
    let mut read = 0;
    for entry in ds.committed(PAIRS_TABLE)?.values() {
        let path = ds.shard_file(entry);
        let mut rows = Vec::new();
        for batch in ds.read_shard_batches(entry)? {
            // The filter is planned on the current schema: a version-1 shard is upgraded first.
            let batch = to_current(&batch).map_err(|e| Error::input(&path, e.to_string()))?;
            let selected = filter.select(&batch)?;
            rows.extend(batch_to_pairs(&selected).map_err(|e| Error::input(&path, e.to_string()))?);
        }
        read += entry.rows;
        bar.inc(entry.rows);
        rows.sort_by_key(|r| r.unit_index);
        for row in rows {
            if !f(row)? {
                return Ok(read);
            }
        }
    }
    Ok(read)
}

/// A file-name-safe form of a key: characters other than ASCII letters, digits, `.`, `-` and `_`
/// become `_` (`synthetic-0/frame-000000#0` → `synthetic-0_frame-000000_0`).
pub fn sanitize(key: &str) -> String {
    let s: String = key.chars().map(|c| if c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_') { c } else { '_' }).collect();
    if s.is_empty() || s.chars().all(|c| c == '.') {
        format!("_{s}")
    } else {
        s
    }
}

/// A unique file name for `key` among those already `used`: [`sanitize`]d, with `~<unit_index>`
/// appended when two keys sanitize to the same name.
pub fn unique_name(used: &mut std::collections::HashSet<String>, key: &str, unit_index: u64) -> String {
    let mut name = sanitize(key);
    if used.contains(&name) {
        name = format!("{name}~{unit_index}");
    }
    used.insert(name.clone());
    name
}

/// Creates `dir`, refusing one that exists and is not empty (an export never mixes with old files).
pub fn create_empty_dir(dir: &std::path::Path) -> Result<()> {
    if let Ok(mut entries) = std::fs::read_dir(dir) {
        if entries.next().is_some() {
            return Err(Error::config("--out", format!("{} exists and is not empty; choose a new folder or remove it", dir.display())));
        }
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sanitize_and_unique_names() {
        assert_eq!(sanitize("synthetic-0/frame-000000#0"), "synthetic-0_frame-000000_0");
        assert_eq!(sanitize(".."), "_..");
        let mut used = Default::default();
        assert_eq!(unique_name(&mut used, "a/b", 1), "a_b");
        assert_eq!(unique_name(&mut used, "a#b", 2), "a_b~2");
    }

    #[test]
    fn refuses_a_non_empty_out_folder() {
        let dir = tempfile::tempdir().unwrap();
        create_empty_dir(&dir.path().join("new/sub")).unwrap();
        create_empty_dir(&dir.path().join("new/sub")).unwrap();
        let e = create_empty_dir(&dir.path().join("new")).unwrap_err().to_string();
        assert!(e.contains("not empty"), "{e}");
    }
}
