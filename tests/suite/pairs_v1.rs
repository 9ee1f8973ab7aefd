//! A dataset of schema `pairs/1`, built by the code before schema version 2 (tests/fixtures/pairs-v1, from
//! tests/fixtures/pairs-v1.toml), is still read by `verify`, `query`, `export` and the library, and a build
//! resumed on it writes its missing shard in version 1, the same rows the old code wrote; a fresh build
//! of the same config gives the same pairs in version 2, plus provenance.

use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::{PairRow, SCHEMA_VERSION_KEY};
use std::path::{Path, PathBuf};
use crate::support::bin;

fn fixture() -> (PathBuf, PathBuf) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");
    (root.join("pairs-v1"), root.join("pairs-v1.toml"))
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), &target).unwrap();
        }
    }
}

fn run_ok(args: &[&str]) -> String {
    let o = bin().args(args).output().unwrap();
    assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// The `schema_version` a Parquet file's Arrow schema records.
fn file_version(path: &Path) -> String {
    let (schema, _) = pointreggpt::shards::read_parquet_file(path).unwrap();
    schema.metadata().get(SCHEMA_VERSION_KEY).cloned().unwrap_or_default()
}

fn without_provenance(rows: &[PairRow]) -> Vec<PairRow> {
    rows.iter().map(|r| PairRow { target_known_share: Vec::new(), target_scene_share: Vec::new(), target_view: Vec::new(), timings: Vec::new(), ..r.clone() }).collect()
}

#[test]
fn a_version_1_dataset_is_read_exported_verified_and_resumed() {
    let _timing = crate::support::timed();
    let (fixture, config) = fixture();
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("v1");
    copy_dir(&fixture, &ds);
    let text = std::fs::read_to_string(ds.join("dataset.toml")).unwrap();
    assert!(text.contains("dataset.schema_version = \"pairs/1\""), "the fixture is a version-1 dataset");
    let old_rows = Dataset::open(&ds).unwrap().read_pairs().unwrap();
    assert_eq!(old_rows.len(), 6);
    assert!(old_rows.iter().all(|r| r.target_known_share.is_empty() && r.target_view.is_empty()), "no provenance in version 1");

    // verify, query (with the version-1 types) and export.
    let v = run_ok(&["verify", ds.to_str().unwrap()]);
    assert!(v.contains("pairs: 3 shards intact, 6 rows") && v.contains("verify: ok"), "{v}");
    let csv = run_ok(&["query", ds.to_str().unwrap(), "select unit_index, seed, sample_index from pairs order by unit_index", "--format", "csv"]);
    let lines: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(lines.len(), 6, "{csv}");
    for (line, r) in lines.iter().zip(&old_rows) {
        assert_eq!(*line, format!("{},{},{}", r.unit_index, r.seed, r.sample_index), "the query gives the rows' unsigned values");
    }
    let types = run_ok(&["query", ds.to_str().unwrap(), "select arrow_typeof(seed) t from pairs limit 1", "--format", "csv"]);
    assert!(types.contains("UInt64"), "{types}");
    let geo = dir.path().join("geo");
    let e = run_ok(&["export", ds.to_str().unwrap(), "--format", "geotransformer", "--out", geo.to_str().unwrap(), "--no-progress"]);
    let ok = old_rows.iter().filter(|r| r.status == pointreggpt::shards::Status::Ok).count();
    assert!(e.contains(&format!("wrote {ok} pairs")), "{e}");
    let clouds = std::fs::read_dir(geo.join("data/train/synthetic-0")).unwrap().count();
    assert_eq!(clouds, 2 * ok, "two clouds per pair and no provenance files");

    // A resumed build: shard 2 withdrawn (as if the first build had been killed before it) is redone in
    // version 1, with the rows the old code wrote.
    std::fs::remove_file(ds.join("manifest/pairs-000002.json")).unwrap();
    std::fs::remove_file(ds.join("shards/pairs-000002.parquet")).unwrap();
    let b = run_ok(&["build", config.to_str().unwrap(), "--out", ds.to_str().unwrap(), "--no-progress"]);
    assert!(b.contains("2 shards already committed, 1 committed now"), "{b}");
    assert_eq!(file_version(&ds.join("shards/pairs-000002.parquet")), "pairs/1");
    let resumed = Dataset::open(&ds).unwrap().read_pairs().unwrap();
    let digests = |rows: &[PairRow]| rows.iter().map(|r| r.content_digest()).collect::<Vec<_>>();
    assert_eq!(digests(&resumed), digests(&old_rows), "the resumed shard holds the rows the old code wrote");
    assert!(run_ok(&["verify", ds.to_str().unwrap()]).contains("pairs: 3 shards intact, 6 rows"));

    // A fresh build of the same config: the current version, the same pairs, and provenance.
    let fresh = dir.path().join("current");
    run_ok(&["build", config.to_str().unwrap(), "--out", fresh.to_str().unwrap(), "--no-progress"]);
    assert_eq!(file_version(&fresh.join("shards/pairs-000000.parquet")), pointreggpt::shards::SCHEMA_VERSION);
    let new_rows = Dataset::open(&fresh).unwrap().read_pairs().unwrap();
    assert!(new_rows.iter().filter(|r| !r.target_points.is_empty()).all(|r| r.target_known_share.len() == r.target_points.len()));
    assert_eq!(without_provenance(&new_rows), without_provenance(&old_rows), "the same pairs as the old code");
}

/// A varied row: an `ok` row with clouds and provenance, or a rejected one without.
fn row(u: u64) -> PairRow {
    let n = if u % 3 == 2 { 0 } else { 5 + u as usize };
    PairRow {
        unit_index: u,
        pair_key: format!("s/frame-{u:06}#0"),
        seed: u64::MAX - 5 * u, // above i64::MAX: stored as a negative int64
        sample_index: u as u32,
        width: 256,
        height: 256,
        pose_draws: 3,
        target_points: (0..n).map(|i| pointreggpt::geometry::Point::new(i as f32, 0.5, 1.0)).collect(),
        target_known_share: (0..n).map(|i| (i % 3) as f32 / 2.0).collect(),
        target_scene_share: (0..n).map(|i| (i % 2) as f32 / 4.0).collect(),
        target_view: (0..n).map(|i| (i % 2) as u8).collect(),
        ..PairRow::default()
    }
}

#[test]
fn version_1_batches_convert_both_ways_bit_for_bit() {
    let _timing = crate::support::timed();
    use arrow::array::{Array, Int64Array, UInt64Array};
    use pointreggpt::shards::pairs_versions::{downgrade, is_v1, to_current};
    use pointreggpt::shards::SCHEMA_VERSION_1;
    use pointreggpt::shards::{batch_to_pairs, pairs_to_batch};
    let rows: Vec<PairRow> = (0..6).map(row).collect();
    let v2 = pairs_to_batch(&rows).unwrap();
    // Version 2 stores the seed bit for bit as int64 (checked against the two's complement by hand).
    let seeds = v2.column_by_name("seed").unwrap().as_any().downcast_ref::<Int64Array>().unwrap();
    assert_eq!(seeds.value(0), -1);
    assert_eq!(seeds.value(1), -6);
    assert_eq!(batch_to_pairs(&v2).unwrap(), rows, "a version-2 round trip is exact");
    // Down to version 1: the unsigned values themselves, no provenance columns.
    let v1 = downgrade(&v2, SCHEMA_VERSION_1).unwrap();
    assert!(is_v1(&v1));
    assert_eq!(v1.num_columns(), 28);
    let seeds = v1.column_by_name("seed").unwrap().as_any().downcast_ref::<UInt64Array>().unwrap();
    assert_eq!(seeds.values().to_vec(), rows.iter().map(|r| r.seed).collect::<Vec<_>>());
    // Read back: the same rows without provenance; and up and down again gives the same batch.
    assert_eq!(batch_to_pairs(&v1).unwrap(), without_provenance_keep_timings(&rows));
    assert_eq!(downgrade(&to_current(&v1).unwrap(), SCHEMA_VERSION_1).unwrap(), v1);
    assert_eq!(to_current(&v1).unwrap().column_by_name("target_known_share").unwrap().len(), 6);
    // A batch labelled version 2 with version-1 columns is refused, naming the column.
    let mislabelled = arrow::array::RecordBatch::try_new(
        std::sync::Arc::new(arrow::datatypes::Schema::new_with_metadata(v1.schema().fields().clone(), v2.schema().metadata().clone())),
        v1.columns().to_vec(),
    )
    .unwrap();
    let e = to_current(&mislabelled).unwrap_err().to_string();
    assert!(e.contains(pointreggpt::shards::SCHEMA_VERSION) && e.contains("unit_index"), "{e}");
}

fn without_provenance_keep_timings(rows: &[PairRow]) -> Vec<PairRow> {
    rows.iter().map(|r| PairRow { target_known_share: Vec::new(), target_scene_share: Vec::new(), target_view: Vec::new(), ..r.clone() }).collect()
}

#[test]
fn version_2_batches_convert_both_ways_and_read_without_a_scene() {
    let _timing = crate::support::timed();
    use pointreggpt::shards::pairs_versions::{downgrade, to_current};
    use pointreggpt::shards::{batch_to_pairs, pairs_to_batch, SCHEMA_VERSION_2};
    // Rows a version-2 build could make: no scene (shares 0, no frames fused).
    let rows: Vec<PairRow> = (0..6)
        .map(row)
        .map(|r| PairRow { target_scene_share: vec![0.0; r.target_known_share.len()], scene_frames: 0, ..r })
        .collect();
    let current = pairs_to_batch(&rows).unwrap();
    let v2 = downgrade(&current, SCHEMA_VERSION_2).unwrap();
    assert_eq!(v2.num_columns(), 30);
    assert!(v2.column_by_name("target_scene_share").is_none() && v2.column_by_name("scene_frames").is_none());
    // Back up: the scene shares are zeros aligned with the known shares, bit for bit the rows written.
    assert_eq!(to_current(&v2).unwrap(), current);
    assert_eq!(batch_to_pairs(&v2).unwrap(), rows);
}
