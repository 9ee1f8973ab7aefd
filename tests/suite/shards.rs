//! Integration tests of the shard sink through the public API: a dataset written by the library is read
//! back by the library and by two independent readers, pyarrow and DuckDB (`tests/python/read_shards.py`),
//! whose counts and sums are compared with values computed from the rows written.

use crate::support;

use pointreggpt::geometry::Point;
use pointreggpt::shards::{
    pairs_schema, pairs_to_batch, write_parquet_bytes, Dataset, PairRow, StageTiming, Status, CODE_VERSION, PAIRS_TABLE,
};
use std::collections::BTreeMap;
use std::path::Path;

const CONFIG: &str = "seed = 11\nshard_size = 7\n[overlap]\nradius = 0.0375\n";
const CONFIG_HASH: &str = "9f2c0e";

/// A small deterministic generator (SplitMix64), independent of the library's RNG.
struct Mix(u64);

impl Mix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }

    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Unit `u`'s row: statuses cycle; clouds of 0..~20k points; some PNG columns empty.
fn row(u: u64) -> PairRow {
    let mut g = Mix(u);
    let status = [Status::Ok, Status::LowOverlap, Status::TooFewPoints, Status::InputError][(u % 4) as usize];
    let big = u == 5 || u == 12;
    let mut cloud = |max: u64| -> Vec<Point> {
        let n = if status == Status::InputError {
            0
        } else if big {
            20_000
        } else {
            g.below(max)
        };
        (0..n).map(|_| Point::new(g.unit() as f32, g.unit() as f32 - 0.5, 0.5 + 3.0 * g.unit() as f32)).collect()
    };
    let source_points = cloud(500);
    let target_points = cloud(300);
    let mut pose = [0.0; 16];
    pose.iter_mut().for_each(|v| *v = g.unit() - 0.5);
    PairRow {
        unit_index: u,
        pair_key: format!("kitchen/frame-{:06}#{}", u / 2, u % 2),
        scene: "kitchen".into(),
        frame_key: format!("kitchen/frame-{:06}", u / 2),
        sample_index: (u % 2) as u32,
        source_path: format!("/data/kitchen/seq-01/frame-{:06}.depth.png", u / 2),
        source_hash: blake3::hash(&(u / 2).to_le_bytes()).to_hex().to_string(),
        status,
        message: if status == Status::Ok { String::new() } else { format!("{} for unit {u}", status.as_str()) },
        seed: g.next(),
        width: 320,
        height: 240,
        source_intrinsics: [292.5, 292.5, 159.5, 119.5],
        target_intrinsics: [292.5, 292.5, 160.0 + g.unit(), 120.0],
        t_target_from_source: pose,
        pose_draws: 1 + g.below(5) as u32,
        scene_frames: (u % 4) as u32 * 10,
        target_known_share: (0..target_points.len()).map(|i| (i % 3) as f32 * 0.5).collect(),
        target_scene_share: (0..target_points.len()).map(|i| if i % 3 == 0 { 0.75 } else { 0.0 }).collect(),
        target_view: (0..target_points.len()).map(|i| (i % 2) as u8).collect(),
        source_points,
        target_points,
        // Multiples of 0.05 land on both sides of 0.4 by a rounding error: float64 keeps every reader equal.
        overlap_source: (u % 12) as f64 * 0.05,
        overlap_target: g.unit(),
        source_depth_png: (0..g.below(2000)).map(|i| i as u8).collect(),
        condition_depth_png: if u % 3 == 0 { vec![] } else { vec![7; 100] },
        target_depth_png: vec![],
        known_mask_png: vec![255; (u % 5) as usize],
        config_hash: CONFIG_HASH.into(),
        code_version: CODE_VERSION.into(),
        stages: r#"[{"name":"reproject"},{"name":"inpaint","model":"classic"}]"#.into(),
        timings: vec![StageTiming { stage: "reproject".into(), ms: g.unit() * 10.0 }],
    }
}

/// Writes units 0..19 as shards of 7 (0..7, 7..14, 14..19), plus an uncommitted shard file and a
/// temporary file that no reader may see. Returns the committed rows.
fn write_dataset(root: &Path) -> Vec<PairRow> {
    let ds = Dataset::create_or_open(root, CONFIG, CONFIG_HASH).unwrap().with_worker("test-0-of-1");
    let rows: Vec<PairRow> = (0..19).map(row).collect();
    // Commit out of order, as parallel workers would.
    for shard in [2u64, 0, 1] {
        let (a, b) = (shard * 7, (shard * 7 + 7).min(19));
        ds.commit_pairs(shard, a, b - a, &rows[a as usize..b as usize]).unwrap();
    }
    let extra: Vec<PairRow> = (19..26).map(row).collect();
    let bytes = write_parquet_bytes(&pairs_schema(), &[pairs_to_batch(&extra).unwrap()], pointreggpt::shards::ROW_GROUP_ROWS).unwrap();
    std::fs::write(ds.shard_path(PAIRS_TABLE, 3), &bytes).unwrap();
    std::fs::write(ds.tmp_dir().join("otherhost~1~pairs-000004.parquet~1.tmp"), &bytes).unwrap();
    rows
}

#[test]
fn library_reads_back_exactly_what_it_committed() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let rows = write_dataset(dir.path());
    let ds = Dataset::open(dir.path()).unwrap();
    assert_eq!(ds.header().config_hash, CONFIG_HASH);
    let back = ds.read_pairs().unwrap();
    assert_eq!(back.len(), 19, "the uncommitted shard 3 is invisible");
    assert_eq!(back, rows);
    let digests = |r: &[PairRow]| r.iter().map(PairRow::content_digest).collect::<Vec<_>>();
    assert_eq!(digests(&back), digests(&rows));
    let committed = ds.committed(PAIRS_TABLE).unwrap();
    assert_eq!(committed.keys().copied().collect::<Vec<_>>(), [0, 1, 2]);
    assert_eq!((committed[&2].first_unit, committed[&2].units, committed[&2].rows), (14, 5, 5));
    let report = ds.verify().unwrap();
    assert!(report.is_ok(), "{report}");
    assert_eq!(report.orphans, [ds.shard_path(PAIRS_TABLE, 3)]);
    assert_eq!(report.other_temps.len(), 1, "{report}");
    // Reopening with another config is refused and names the key.
    let err = Dataset::create_or_open(dir.path(), &CONFIG.replace("seed = 11", "seed = 12"), "other").unwrap_err();
    assert!(err.to_string().contains("seed: 11 → 12"), "{err}");
}

/// What the Python readers must report, computed from the committed rows.
fn expected(rows: &[PairRow]) -> serde_json::Value {
    let mut by_status: BTreeMap<&str, u64> = BTreeMap::new();
    for r in rows {
        *by_status.entry(r.status.as_str()).or_default() += 1;
    }
    serde_json::json!({
        "rows": rows.len(),
        "rows_by_status": by_status,
        "source_points": rows.iter().map(|r| r.source_points.len()).sum::<usize>(),
        "target_points": rows.iter().map(|r| r.target_points.len()).sum::<usize>(),
        "mean_overlap_source": rows.iter().map(|r| r.overlap_source).sum::<f64>() / rows.len() as f64,
        "overlap_at_least_0_4": rows.iter().filter(|r| r.overlap_source >= 0.4).count(),
    })
}

/// Fails (does not skip) when pyarrow or DuckDB is missing.
fn require_python_modules() {
    let ok = support::python_command()
        .args(["-c", "import pyarrow, duckdb"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    assert!(
        ok,
        "`{} -c 'import pyarrow, duckdb'` failed: run scripts/install-test-deps.sh (installs the pinned pyarrow \
         and duckdb this test reads the shards with)",
        support::python()
    );
}

#[test]
fn pyarrow_and_duckdb_read_the_committed_shards() {
    let _timing = crate::support::timed();
    require_python_modules();
    let dir = tempfile::tempdir().unwrap();
    let rows = write_dataset(dir.path());
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/python/read_shards.py");
    let out = support::python_command().arg(script).arg(dir.path()).output().unwrap();
    assert!(out.status.success(), "read_shards.py failed:\n{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        report["files"],
        serde_json::json!(["pairs-000000.parquet", "pairs-000001.parquet", "pairs-000002.parquet"])
    );
    assert_eq!(report["schema_versions"], serde_json::json!([pointreggpt::shards::SCHEMA_VERSION]));

    let want = expected(&rows);
    // Sanity of the expectation itself: every status occurs, and the 0.4 threshold splits the rows.
    assert_eq!(want["rows_by_status"].as_object().unwrap().len(), 4);
    let high = want["overlap_at_least_0_4"].as_u64().unwrap();
    assert!(high > 0 && high < 19, "{want}");
    assert!(want["source_points"].as_u64().unwrap() > 40_000);

    for reader in ["pyarrow", "duckdb"] {
        let got = &report[reader];
        for key in ["rows", "rows_by_status", "source_points", "target_points", "overlap_at_least_0_4"] {
            assert_eq!(got[key], want[key], "{reader}: {key} ({})", report["versions"]);
        }
        let (g, w) = (got["mean_overlap_source"].as_f64().unwrap(), want["mean_overlap_source"].as_f64().unwrap());
        assert!((g - w).abs() <= 1e-12 * w.abs(), "{reader}: mean overlap_source {g} vs {w}");
    }
}
