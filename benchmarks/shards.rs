//! Shard write and read throughput: our Parquet writer/reader (rows ↔ Arrow ↔ zstd Parquet) against
//! pyarrow writing and reading the very same table, in the same run; then the dataset's commit and read
//! on a local S3 server (moto, as in tests/store.rs) against a local folder: throughput of whole shards
//! and the latency of committing small shards. Run: `cargo bench --bench shards`.

#[path = "../tests/support/mod.rs"]
#[allow(dead_code)]
mod support;

use support::store;

use pointreggpt::geometry::Point;
use pointreggpt::rng::Rng;
use pointreggpt::shards::row::{PairRow, StageTiming, Status};
use pointreggpt::shards::{batch_to_pairs, pairs_schema, pairs_to_batch, read_parquet_file, write_parquet_bytes, ROW_GROUP_ROWS};
use std::time::Instant;

/// A realistic row: two ~10k-point clouds (2.5 cm voxels of a 256×256 view) and three depth PNGs.
fn row(i: u64, rng: &mut Rng) -> PairRow {
    let cloud = |rng: &mut Rng, n: usize| -> Vec<Point> {
        (0..n).map(|_| Point::new(rng.uniform_range(-1.5, 1.5) as f32, rng.uniform_range(-1.5, 1.5) as f32, rng.uniform_range(0.5, 3.5) as f32)).collect()
    };
    let png = |rng: &mut Rng| -> Vec<u8> {
        let d: Vec<u16> = (0..256 * 256).map(|k| 1000 + (k % 256) as u16 * 4 + (rng.below(3) as u16)).collect();
        pointreggpt::sources::depth_png::encode_depth_png(256, 256, &d).unwrap()
    };
    PairRow {
        unit_index: i,
        pair_key: format!("scene/frame-{i:06}#0"),
        scene: "scene".into(),
        frame_key: format!("scene/frame-{i:06}"),
        sample_index: 0,
        source_path: format!("/data/scene/frame-{i:06}.depth.png"),
        source_hash: blake3::hash(&i.to_le_bytes()).to_hex().to_string(),
        status: Status::Ok,
        message: String::new(),
        seed: rng.next_u64(),
        width: 256,
        height: 256,
        source_intrinsics: [311.7, 312.0, 128.5, 128.0],
        target_intrinsics: [311.7, 312.0, 128.5, 128.0],
        t_target_from_source: std::array::from_fn(|k| if k % 5 == 0 { 1.0 } else { 0.0 }),
        pose_draws: 1,
        source_points: cloud(rng, 10_000),
        target_points: cloud(rng, 9_000),
        target_known_share: (0..9_000).map(|k| if k % 4 == 0 { 0.0 } else { 1.0 }).collect(),
        target_view: vec![0; 9_000],
        overlap_source: rng.uniform(),
        overlap_target: rng.uniform(),
        source_depth_png: png(rng),
        condition_depth_png: png(rng),
        target_depth_png: png(rng),
        known_mask_png: vec![0; 2000],
        config_hash: "0".repeat(64),
        code_version: "pointreggpt bench".into(),
        stages: "[]".into(),
        timings: vec![StageTiming { stage: "ingest".into(), ms: 1.0 }],
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let n = 200;
    let mut rng = Rng::new(1);
    let rows: Vec<PairRow> = (0..n).map(|i| row(i, &mut rng)).collect();
    let dir = std::env::temp_dir().join("pointreggpt-bench-shards");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("pairs-000000.parquet");

    let reps = 5;
    let mut write_ms = Vec::new();
    let mut bytes = Vec::new();
    for _ in 0..reps {
        let t = Instant::now();
        let batch = pairs_to_batch(&rows).unwrap();
        bytes = write_parquet_bytes(&pairs_schema(), &[batch], ROW_GROUP_ROWS).unwrap();
        std::fs::write(&path, &bytes).unwrap();
        write_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let mut read_ms = Vec::new();
    for _ in 0..reps {
        let t = Instant::now();
        let (_, batches) = read_parquet_file(&path).unwrap();
        let back: Vec<PairRow> = batches.iter().flat_map(|b| batch_to_pairs(b).unwrap()).collect();
        assert_eq!(back.len(), n as usize);
        read_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let (ours_w, ours_r) = (median(write_ms), median(read_ms));

    let script = r#"
import sys, time, statistics
import pyarrow.parquet as pq
path, reps = sys.argv[1], int(sys.argv[2])
t = pq.read_table(path)
r = []
for _ in range(reps):
    s = time.perf_counter(); x = pq.read_table(path); x.column("source_points").to_numpy(zero_copy_only=False); r.append((time.perf_counter() - s) * 1e3)
w = []
for _ in range(reps):
    s = time.perf_counter(); pq.write_table(t, path + ".pyarrow", compression="zstd", compression_level=3); w.append((time.perf_counter() - s) * 1e3)
print(statistics.median(w), statistics.median(r))
"#;
    let py = support::python_command()
        .args(["-c", script])
        .arg(&path)
        .arg(reps.to_string())
        .output()
        .expect("python3");
    let (peer_w, peer_r) = if py.status.success() {
        let out = String::from_utf8_lossy(&py.stdout);
        let v: Vec<f64> = out.split_whitespace().map(|x| x.parse().unwrap()).collect();
        (Some(v[0]), Some(v[1]))
    } else {
        eprintln!("pyarrow peer failed (run scripts/install-test-deps.sh): {}", String::from_utf8_lossy(&py.stderr));
        (None, None)
    };
    let mb = bytes.len() as f64 / 1e6;
    println!("shard of {n} rows (2 x ~10k points, 3 depth PNGs each): {mb:.1} MB zstd Parquet, median of {reps}");
    println!("{:<28} {:>10} {:>12} {:>12} {:>14}", "operation", "ours ms", "ours MB/s", "pyarrow ms", "pyarrow/ours");
    for (name, ours, peer) in [("write (rows -> file)", ours_w, peer_w), ("read (file -> rows)", ours_r, peer_r)] {
        let (p, ratio) = match peer {
            Some(p) => (format!("{p:.1}"), format!("{:.2}", p / ours)),
            None => ("n/a".into(), "n/a".into()),
        };
        println!("{name:<28} {ours:>10.1} {:>12.1} {p:>12} {ratio:>14}", mb / (ours / 1e3));
    }
    println!("(pyarrow writes the same Arrow table with zstd level 3; its read includes materialising the point lists)");
    let _ = std::fs::remove_dir_all(&dir);
    store_vs_folder(&rows);
}

/// Commits and reads of whole shards, and the commit latency of small shards, on moto vs a folder.
fn store_vs_folder(rows: &[PairRow]) {
    use pointreggpt::shards::dataset::Dataset;
    let moto = store::Moto::start();
    moto.set_env();
    moto.create_bucket("bench");
    let dir = tempfile::tempdir().unwrap();
    let local = dir.path().join("ds");
    let targets = [("folder", local.to_str().unwrap().to_string()), ("s3 (moto)", "s3://bench/ds".to_string())];
    let n = rows.len() as u64;
    let reps = 3;
    println!();
    println!("dataset commit and read: local S3 server (moto on 127.0.0.1) vs a folder, median of {reps}");
    println!("{:<12} {:>14} {:>14} {:>14} {:>14} {:>20}", "where", "commit ms", "commit MB/s", "read ms", "read MB/s", "small commit ms/shard");
    let mut results = Vec::new();
    for (name, at) in &targets {
        let ds = Dataset::create_or_open(at, "seed = 1\n", "bench").unwrap();
        let (mut commit, mut read, mut mb) = (Vec::new(), Vec::new(), 0.0);
        for rep in 0..reps {
            let t = Instant::now();
            let entry = ds.commit_pairs(rep, rep * n, n, rows).unwrap();
            commit.push(t.elapsed().as_secs_f64() * 1e3);
            mb = entry.bytes as f64 / 1e6;
            let t = Instant::now();
            let back: usize = ds.read_shard_batches(&entry).unwrap().iter().map(|b| batch_to_pairs(b).unwrap().len()).sum();
            read.push(t.elapsed().as_secs_f64() * 1e3);
            assert_eq!(back as u64, n);
        }
        // Commit latency: 20 shards of one small row each (no clouds, no PNGs).
        let small = PairRow { unit_index: 0, ..Default::default() };
        let mut latency = Vec::new();
        for k in 0..20u64 {
            let t = Instant::now();
            ds.commit_pairs(100 + k, 1000 + k, 1, &[PairRow { unit_index: 1000 + k, ..small.clone() }]).unwrap();
            latency.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let (c, r, l) = (median(commit), median(read), median(latency));
        println!("{name:<12} {c:>14.1} {:>14.1} {r:>14.1} {:>14.1} {l:>20.2}", mb / (c / 1e3), mb / (r / 1e3));
        results.push((c, r, l));
    }
    let (f, s) = (results[0], results[1]);
    println!(
        "s3/folder time ratios: commit {:.2}, read {:.2}, small-shard commit latency {:.2} ({mb_note})",
        s.0 / f.0,
        s.1 / f.1,
        s.2 / f.2,
        mb_note = "a shard commit on the store is 4 requests: upload record, object, create-only manifest entry, record delete"
    );
}
