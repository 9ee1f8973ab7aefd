//! `pointreggpt query` (DataFusion) against DuckDB running the same SQL over the same committed files.

mod support;

use pointreggpt::pipeline::{run_build, BuildConfig, BuildOptions};
use pointreggpt::runtime::CancelToken;
use std::path::Path;
use support::{bin, python, synthetic_config};

fn dataset(dir: &Path) -> std::path::PathBuf {
    let text = synthetic_config(2, 16, 2, 1, 320, 240, 3) + "[validate]\nmin_overlap = 0.6\n";
    let config = BuildConfig::from_toml(&text, "t").unwrap();
    let out = dir.join("ds");
    let opts = BuildOptions { out: out.clone(), worker: 0, workers: 1, strict: false, progress: false };
    run_build(&config, &opts, &CancelToken::new()).unwrap();
    out
}

/// Our answer as rows of cells, parsed from `--format csv`.
fn ours(ds: &Path, sql: &str) -> Vec<Vec<String>> {
    let o = bin().args(["query"]).arg(ds).arg(sql).args(["--format", "csv"]).output().unwrap();
    assert!(o.status.success(), "{sql}: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap().lines().skip(1).map(|l| l.split(',').map(str::to_string).collect()).collect()
}

fn same_cell(ours: &str, theirs: &serde_json::Value) -> bool {
    match theirs {
        serde_json::Value::Number(n) => {
            let (a, b) = (ours.parse::<f64>().unwrap_or(f64::NAN), n.as_f64().unwrap());
            (a - b).abs() <= 1e-9 * b.abs().max(1.0)
        }
        serde_json::Value::String(s) => ours == s,
        serde_json::Value::Null => ours.is_empty(),
        other => ours == other.to_string(),
    }
}

#[test]
fn query_answers_match_duckdb_on_the_same_files() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let queries = [
        "select status, count(*) as n from pairs group by status order by status",
        "select scene, count(*) as n, avg(overlap_source) as ov from pairs where status = 'ok' group by scene order by scene",
        "select floor(overlap_source * 10) / 10 as bin, count(*) as n from pairs group by floor(overlap_source * 10) / 10 order by bin",
        "select sum(array_length(source_points)) as pts, sum(array_length(target_points)) as tgt from pairs",
        "select count(*) as n from pairs where overlap_source >= 0.3 and overlap_target < 0.9",
        "select pair_key, pose_draws, sample_index from pairs order by unit_index limit 5",
    ];
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/duckdb_query.py");
    let py = std::process::Command::new(python()).arg(&script).arg(&ds).args(queries).output().unwrap();
    assert!(py.status.success(), "run scripts/install-test-deps.sh: {}", String::from_utf8_lossy(&py.stderr));
    let theirs: Vec<Vec<Vec<serde_json::Value>>> =
        String::from_utf8(py.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    for (q, t) in queries.iter().zip(&theirs) {
        let o = ours(&ds, q);
        assert_eq!(o.len(), t.len(), "{q}: row counts {o:?} vs {t:?}");
        for (ro, rt) in o.iter().zip(t) {
            assert_eq!(ro.len(), rt.len(), "{q}");
            for (a, b) in ro.iter().zip(rt) {
                let b = match b {
                    serde_json::Value::Bool(v) => serde_json::Value::String(v.to_string()),
                    other => other.clone(),
                };
                assert!(same_cell(a, &b), "{q}: ours {a} vs duckdb {b}");
            }
        }
    }
    // A query with at least one rejected row proves both see the same rejects.
    assert!(theirs[0].len() >= 2, "the dataset has rejects: {:?}", theirs[0]);
}

#[test]
fn manifest_table_and_output_formats() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let o = ours(&ds, "select count(*) as shards, sum(rows) as rows from manifest where \"table\" = 'pairs'");
    let shards = std::fs::read_dir(ds.join("manifest")).unwrap().count();
    assert_eq!(o, vec![vec![shards.to_string(), "16".to_string()]]);

    let json = bin().args(["query"]).arg(&ds).args(["select status, count(*) as n from pairs group by status", "--format", "json"]).output().unwrap();
    let total: u64 = String::from_utf8(json.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["n"].as_u64().unwrap())
        .sum();
    assert_eq!(total, 16);

    let parquet = dir.path().join("r.parquet");
    let st = bin().args(["query"]).arg(&ds).args(["select unit_index, overlap_source from pairs", "--format", "parquet", "--output"]).arg(&parquet).status().unwrap();
    assert!(st.success());
    let (_, batches) = pointreggpt::shards::read_parquet_file(&parquet).unwrap();
    assert_eq!(batches.iter().map(|b| b.num_rows()).sum::<usize>(), 16);

    // An uncommitted shard file is invisible; a bad query names the problem.
    std::fs::copy(ds.join("shards/pairs-000000.parquet"), ds.join("shards/pairs-000099.parquet")).unwrap();
    assert_eq!(ours(&ds, "select count(*) from pairs"), vec![vec!["16".to_string()]]);
    let bad = bin().args(["query"]).arg(&ds).arg("select nosuchcolumn from pairs").output().unwrap();
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("nosuchcolumn"));
}
