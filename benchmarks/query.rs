//! `pointreggpt query` (DataFusion over the committed shards) against DuckDB running the same SQL over the
//! same committed files, in the same run: a dataset of 100 shards x 1,000 pairs (100k pairs, the size users
//! build) with small clouds (64 + 58 points, so the metadata columns dominate as they do for the queries
//! users write). Each time includes opening the dataset and planning (ours: `run_query`, as the CLI does;
//! DuckDB: connect, a view over the manifest's files, execute, timed inside Python after its imports).
//! This is the benchmark behind the DataFusion crates' opt-level in Cargo.toml. Run:
//! `cargo bench --bench query`.

#[path = "common/mod.rs"]
mod common;

#[path = "../tests/support/mod.rs"]
#[allow(dead_code)]
mod support;

use pointreggpt::geometry::Point;
use pointreggpt::query::run_query;
use pointreggpt::rng::Rng;
use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::row::{PairRow, Status};

const SHARDS: u64 = 100;
const ROWS_PER_SHARD: u64 = 1_000;

/// The queries timed: the ones tests/query.rs checks against DuckDB, on a dataset of realistic size.
const QUERIES: [(&str, &str); 5] = [
    ("count by status", "select status, count(*) as n from pairs group by status order by status"),
    (
        "avg overlap by scene, filtered",
        "select scene, count(*) as n, avg(overlap_source) as ov from pairs where status = 'ok' group by scene order by scene",
    ),
    (
        "overlap histogram",
        "select floor(overlap_source * 10) / 10 as bin, count(*) as n from pairs group by floor(overlap_source * 10) / 10 order by bin",
    ),
    ("points per cloud (lists)", "select sum(array_length(source_points)) as pts, sum(array_length(target_points)) as tgt from pairs"),
    ("top 100 by overlap", "select pair_key, overlap_source from pairs order by overlap_source desc limit 100"),
];

fn cloud(rng: &mut Rng, n: usize) -> Vec<Point> {
    (0..n).map(|_| Point::new(rng.uniform_range(-1.5, 1.5) as f32, rng.uniform_range(-1.5, 1.5) as f32, rng.uniform_range(0.5, 3.5) as f32)).collect()
}

fn row(i: u64, rng: &mut Rng) -> PairRow {
    let scene = format!("scene-{:02}", i % 16);
    let status = match rng.below(10) {
        0 => Status::LowOverlap,
        1 => Status::TooFewPoints,
        _ => Status::Ok,
    };
    PairRow {
        unit_index: i,
        pair_key: format!("{scene}/frame-{i:06}#0"),
        frame_key: format!("{scene}/frame-{i:06}"),
        scene,
        status,
        seed: rng.next_u64(),
        width: 320,
        height: 240,
        source_points: cloud(rng, 64),
        target_points: cloud(rng, 58),
        target_known_share: vec![1.0; 58],
        target_view: vec![0; 58],
        overlap_source: rng.uniform(),
        overlap_target: rng.uniform(),
        config_hash: "bench".into(),
        ..Default::default()
    }
}

fn main() {
    let dir = std::env::temp_dir().join("pointreggpt-bench-query");
    let _ = std::fs::remove_dir_all(&dir);
    let ds = Dataset::create_or_open(&dir, "seed = 1\n", "bench").unwrap();
    let mut rng = Rng::new(7);
    for s in 0..SHARDS {
        let rows: Vec<PairRow> = (s * ROWS_PER_SHARD..(s + 1) * ROWS_PER_SHARD).map(|i| row(i, &mut rng)).collect();
        ds.commit_pairs(s, s * ROWS_PER_SHARD, ROWS_PER_SHARD, &rows).unwrap();
    }
    let reps = 5;
    let ours: Vec<(f64, usize)> = QUERIES
        .iter()
        .map(|(_, sql)| {
            let (ms, batches) = common::median_ms(1, reps, || run_query(&dir, sql).unwrap());
            (ms, batches.iter().map(|b| b.num_rows()).sum())
        })
        .collect();

    let script = r#"
import json, os, statistics, sys, time
import duckdb
root, reps, queries = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
def run(q):
    files = []
    for name in sorted(os.listdir(os.path.join(root, "manifest"))):
        if name.startswith("pairs-") and name.endswith(".json"):
            with open(os.path.join(root, "manifest", name)) as f:
                files.append(os.path.join(root, "shards", json.load(f)["file"]))
    con = duckdb.connect()
    con.execute("create view pairs as select * from read_parquet([" + ", ".join("'" + f + "'" for f in files) + "])")
    return con.execute(q).fetchall()
for q in queries:
    n = len(run(q))
    times = []
    for _ in range(reps):
        s = time.perf_counter(); run(q); times.append((time.perf_counter() - s) * 1e3)
    print(statistics.median(times), n)
"#;
    let py = support::python_command()
        .args(["-c", script])
        .arg(&dir)
        .arg(reps.to_string())
        .args(QUERIES.iter().map(|(_, q)| *q))
        .output()
        .expect("python3");
    let peer: Vec<Option<(f64, usize)>> = if py.status.success() {
        String::from_utf8_lossy(&py.stdout)
            .lines()
            .map(|l| {
                let v: Vec<&str> = l.split_whitespace().collect();
                Some((v[0].parse().unwrap(), v[1].parse().unwrap()))
            })
            .collect()
    } else {
        eprintln!("DuckDB peer failed (run scripts/install-test-deps.sh): {}", String::from_utf8_lossy(&py.stderr));
        vec![None; QUERIES.len()]
    };

    println!(
        "dataset: {SHARDS} shards x {ROWS_PER_SHARD} pairs (64 + 58 points each), median of {reps}; cpu {}, load {}",
        common::cpu_model(),
        common::load_average()
    );
    println!("{:<32} {:>10} {:>12} {:>15} {:>6}", "query", "ours ms", "DuckDB ms", "DuckDB/ours", "rows");
    for (((name, _), (ms, rows)), theirs) in QUERIES.iter().zip(&ours).zip(&peer) {
        let (p, ratio) = match theirs {
            Some((p, n)) => {
                assert_eq!(n, rows, "{name}: DuckDB returned {n} rows, we returned {rows}");
                (format!("{p:.1}"), format!("{:.2}", p / ms))
            }
            None => ("n/a".into(), "n/a".into()),
        };
        println!("{name:<32} {ms:>10.1} {p:>12} {ratio:>15} {rows:>6}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
