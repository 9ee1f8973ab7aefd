//! The Python package of `python/` (`pointreggpt_data`, installed by scripts/install-test-deps.sh) reads
//! datasets built by the binary exactly as `pointreggpt query` does: the same rows and pair keys in unit
//! order, the points bit for bit, the transforms, overlaps, unsigned seeds and per-point provenance, the
//! same rows for each filter as the equivalent SQL `where`, and the DataLoader + `collate` path with
//! torch. In a folder and on a local S3 server (moto), for a version-2 dataset and a version-1 one. The
//! streaming loader gives every pair exactly once per epoch across ranks × DataLoader workers.
//! tests/python/check_package.py does the Python side; it fails (never skips) when the package, pyarrow
//! or torch is missing, or when the installed package differs from python/.

use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use crate::support::store::Moto;
use crate::support::{bin, python, synthetic_config};

/// 2 scenes × 4 frames at 160×120, two successive target views (so `target_view` has 0s and 1s), shards
/// of 3 units, `min_overlap = 0.8` so that some rows are rejected (`low_overlap`).
fn config(dir: &Path) -> PathBuf {
    let text = synthetic_config(2, 12, 3, 1, 160, 120, 3) + "[validate]\nmin_overlap = 0.8\n[successive]\nviews = 2\n";
    let path = dir.join("config.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn ok(o: Output, what: &str) -> String {
    assert!(o.status.success(), "{what} failed:\n{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// `pointreggpt <args>` with the environment `env`.
fn run(args: &[&str], env: &[(&str, String)]) -> String {
    let o = bin().args(args).envs(env.iter().map(|(k, v)| (*k, v.as_str()))).output().unwrap();
    ok(o, &format!("pointreggpt {args:?}"))
}

fn build(config: &Path, out: &str, env: &[(&str, String)]) {
    run(&["build", config.to_str().unwrap(), "--out", out, "--no-progress"], env);
}

/// What the package must give, from `pointreggpt query`: every row in unit order as Parquet (exact
/// values), and the pair keys each filter's SQL predicate selects.
struct Reference {
    parquet: PathBuf,
    rows: usize,
    ok: usize,
    filters: Vec<Value>,
}

/// The filters: the package's selection arguments (`kwargs`, `where` as a pyarrow expression) and the
/// SQL predicate that selects the same rows.
fn filter_cases() -> Vec<(Value, Option<&'static str>, &'static str)> {
    vec![
        (json!({"status": "ok"}), None, "status = 'ok'"),
        (json!({"status": null, "scene": "synthetic-1"}), None, "scene = 'synthetic-1'"),
        (json!({"status": null, "overlap_source": [0.85, null], "overlap_target": [null, 0.7]}), None, "overlap_source >= 0.85 and overlap_target <= 0.7"),
        (
            json!({"status": ["ok", "low_overlap"], "scene": ["synthetic-0"], "overlap_target": [0.5, 0.75]}),
            None,
            "status in ('ok', 'low_overlap') and scene in ('synthetic-0') and overlap_target between 0.5 and 0.75",
        ),
        (json!({"status": "ok"}), Some("pc.field('unit_index') >= 4"), "status = 'ok' and unit_index >= 4"),
        (json!({"status": "low_overlap", "overlap_source": [0.0, 1.0]}), None, "status = 'low_overlap' and overlap_source between 0.0 and 1.0"),
        (json!({"status": "too_few_points"}), None, "status = 'too_few_points'"),
    ]
}

/// `varied`: the dataset was built by [`config`], so it has ok and rejected rows and the filters select
/// some rows but not all (checked, so that the comparisons mean something).
fn reference(dataset: &str, dir: &Path, provenance: bool, varied: bool, env: &[(&str, String)]) -> Reference {
    let parquet = dir.join("reference.parquet");
    let columns = "unit_index, pair_key, scene, status, seed, t_target_from_source, source_points, target_points, overlap_source, overlap_target";
    let provenance_columns = if provenance { ", target_known_share, target_scene_share, target_view" } else { "" };
    let sql = format!("select {columns}{provenance_columns} from pairs order by unit_index");
    run(&["query", dataset, &sql, "--format", "parquet", "--output", parquet.to_str().unwrap()], env);
    let keys = |predicate: &str| -> Vec<String> {
        let sql = format!("select pair_key from pairs where {predicate} order by unit_index");
        let out = run(&["query", dataset, &sql, "--format", "json"], env);
        out.lines().map(|l| serde_json::from_str::<Value>(l).unwrap()["pair_key"].as_str().unwrap().to_string()).collect()
    };
    let all = keys("true");
    let ok = keys("status = 'ok'").len();
    let filters: Vec<Value> = filter_cases().into_iter().map(|(kwargs, wh, sql)| json!({"kwargs": kwargs, "where": wh, "keys": keys(sql), "sql": sql})).collect();
    let sizes: Vec<usize> = filters.iter().map(|f| f["keys"].as_array().unwrap().len()).collect();
    assert!(ok > 0, "the dataset has ok rows");
    assert!(!varied || ok < all.len(), "the dataset has ok and rejected rows: {ok} of {}", all.len());
    assert!(!varied || sizes.iter().filter(|&&n| n > 0 && n < all.len()).count() >= 4, "most filters select some rows but not all: {sizes:?}");
    Reference { parquet, rows: all.len(), ok, filters }
}

fn committed_shards(dir: &Path) -> usize {
    std::fs::read_dir(dir.join("manifest")).unwrap().filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().starts_with("pairs-")).count()
}

/// Runs tests/python/check_package.py on `plan` (the reference and source folder added); returns its report.
fn check(mut plan: Value, r: &Reference, dir: &Path, env: &[(&str, String)]) -> Value {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    plan["reference"] = json!(r.parquet);
    plan["filters"] = json!(r.filters);
    plan["source"] = json!(root.join("python/pointreggpt_data"));
    let path = dir.join("plan.json");
    std::fs::write(&path, plan.to_string()).unwrap();
    let mut c = Command::new(python());
    c.arg(root.join("tests/python/check_package.py")).arg(&path).current_dir(dir);
    // Only what the plan names: no AWS credentials or endpoint from this process, no instance metadata.
    for (k, _) in std::env::vars() {
        if k.starts_with("AWS_") || k.starts_with("AZURE_") {
            c.env_remove(k);
        }
    }
    c.env("AWS_EC2_METADATA_DISABLED", "true").envs(env.iter().map(|(k, v)| (*k, v.as_str())));
    let out = ok(
        c.output().unwrap(),
        "check_package.py (pointreggpt_data, pyarrow and torch are required: scripts/install-test-deps.sh installs them, python/ with `pip install ./python`)",
    );
    let report: Value = serde_json::from_str(out.trim().lines().last().unwrap()).unwrap();
    assert_eq!(report["rows"], r.rows, "{report}");
    assert_eq!(report["ok"], r.ok, "{report}");
    assert_eq!(report["loader"]["pairs"], r.ok, "{report}");
    let sizes: Vec<usize> = r.filters.iter().map(|f| f["keys"].as_array().unwrap().len()).collect();
    assert_eq!(report["filters"], json!(sizes), "{report}");
    assert_eq!(report["store_parsing"], true, "{report}");
    report
}

#[test]
fn the_package_reads_a_folder_as_query_does() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let ds = dir.path().join("ds");
    build(&config, ds.to_str().unwrap(), &[]);
    let r = reference(ds.to_str().unwrap(), dir.path(), true, true, &[]);
    let plan = json!({
        "dataset": ds, "storage_options": null, "schema_version": pointreggpt::shards::SCHEMA_VERSION, "shards": committed_shards(&ds),
        "plant_uncommitted": true, "count_bytes": true, "loader_workers": 2,
    });
    let report = check(plan, &r, dir.path(), &[]);
    assert!(report["negative_seeds"].as_u64().unwrap() > 0, "some stored seeds are >= 2^63 (negative int64): {report}");
    assert!(ds.join("shards/pairs-000099-uncommitted.parquet").exists(), "the planted uncommitted shard was there while reading");
    let bytes = &report["bytes"];
    assert!(bytes["index_bytes"].as_u64().unwrap() * 100 < bytes["shard_bytes"].as_u64().unwrap(), "{report}");
}

#[test]
fn the_package_reads_an_s3_dataset_as_query_does() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let moto = Moto::start();
    moto.create_bucket("trainers");
    let env = Moto::vars(&moto.endpoint());
    let url = "s3://trainers/prgpt";
    build(&config, url, &env);
    let r = reference(url, dir.path(), true, true, &env);
    // The same build in a folder gives the same rows (the reference is not a property of the store).
    let local = dir.path().join("local");
    build(&config, local.to_str().unwrap(), &[]);
    let local_ref = dir.path().join("local-ref");
    std::fs::create_dir(&local_ref).unwrap();
    let lr = reference(local.to_str().unwrap(), &local_ref, true, true, &[]);
    assert_eq!(lr.filters, r.filters);
    let plan = json!({
        "dataset": url,
        "storage_options": {"endpoint_url": moto.endpoint(), "access_key": "testing", "secret_key": "testing", "region": "us-east-1"},
        "env": env.iter().map(|(k, v)| (k.to_string(), json!(v))).collect::<serde_json::Map<String, Value>>(),
        "schema_version": pointreggpt::shards::SCHEMA_VERSION, "shards": committed_shards(&local),
        "plant_uncommitted": true, "loader_workers": 2,
    });
    let report = check(plan, &r, dir.path(), &[]);
    assert!(report["planted"].as_str().unwrap().starts_with("trainers/prgpt/shards/"), "{report}");
    assert_eq!(report["env"], true);
}

/// The training loaders at a size where shards have several row groups: 320 units in 5 shards of 72 (row
/// groups of at most 64 rows, `output.row_group_rows`: 9 of them), streamed by 2 ranks × 3 DataLoader workers (neither the 5 shards nor
/// the 9 row groups divide evenly), two epochs; and the map-style dataset in a random order.
#[test]
fn the_streaming_loader_gives_every_pair_once_per_epoch_across_ranks_and_workers() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("config.toml");
    std::fs::write(&config, synthetic_config(1, 160, 1, 2, 160, 120, 72) + "[output]\nrow_group_rows = 64\n").unwrap();
    let ds = dir.path().join("ds");
    build(&config, ds.to_str().unwrap(), &[]);
    assert_eq!(committed_shards(&ds), 5);
    let r = reference(ds.to_str().unwrap(), dir.path(), true, false, &[]);
    let plan = json!({
        "dataset": ds, "storage_options": null, "schema_version": pointreggpt::shards::SCHEMA_VERSION, "shards": 5,
        "any_rows_per_filter": true, "loader_workers": 0, "streaming": {"ranks": 2, "workers": 3},
    });
    let report = check(plan, &r, dir.path(), &[]);
    assert_eq!(report["streaming"]["pieces"], 9, "{report}");
    assert_eq!(report["streaming"]["pairs"], r.ok, "{report}");
}

/// A version-1 dataset made by the product's own version-1 writer: a dataset whose `dataset.toml` says
/// `pairs/1` gets its shards written in version 1 (as a resumed build of an old dataset does,
/// tests/pairs_v1.rs). tests/fixtures/pairs-v1/ (built by the code before version 2) is read too when
/// the checkout has it.
#[test]
fn the_package_reads_version_1_datasets() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let v1 = dir.path().join("v1");
    build(&config, v1.to_str().unwrap(), &[]);
    let header = std::fs::read_to_string(v1.join("dataset.toml")).unwrap();
    let current = format!("dataset.schema_version = \"{}\"", pointreggpt::shards::SCHEMA_VERSION);
    assert!(header.contains(&current));
    std::fs::write(v1.join("dataset.toml"), header.replace(&current, "dataset.schema_version = \"pairs/1\"")).unwrap();
    for sub in ["shards", "manifest"] {
        std::fs::remove_dir_all(v1.join(sub)).unwrap();
        std::fs::create_dir(v1.join(sub)).unwrap();
    }
    build(&config, v1.to_str().unwrap(), &[]);
    let (schema, _) = pointreggpt::shards::read_parquet_file(&v1.join("shards/pairs-000000.parquet")).unwrap();
    assert_eq!(schema.metadata().get(pointreggpt::shards::SCHEMA_VERSION_KEY).map(String::as_str), Some("pairs/1"));
    assert!(schema.field_with_name("target_view").is_err(), "no provenance columns in version 1");
    let r = reference(v1.to_str().unwrap(), dir.path(), false, true, &[]);
    let plan = json!({"dataset": v1, "storage_options": null, "schema_version": "pairs/1", "shards": committed_shards(&v1), "loader_workers": 0});
    check(plan, &r, dir.path(), &[]);

    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/pairs-v1");
    if fixture.join("dataset.toml").exists() {
        let d = dir.path().join("fixture");
        std::fs::create_dir(&d).unwrap();
        let r = reference(fixture.to_str().unwrap(), &d, false, false, &[]);
        let plan = json!({"dataset": fixture, "storage_options": null, "schema_version": "pairs/1", "shards": committed_shards(&fixture), "loader_workers": 0, "any_rows_per_filter": true});
        check(plan, &r, &d, &[]);
    }
}

/// Runs `tests/python/<script>` on `plan` (written to `dir/<script>.json`); returns its report (the last
/// line of its output, JSON). The Python side fails, never skips, when a module it needs is missing.
fn run_script(script: &str, plan: &Value, dir: &Path) -> Value {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let path = dir.join(format!("{script}.json"));
    std::fs::write(&path, plan.to_string()).unwrap();
    let mut c = Command::new(python());
    c.arg(root.join("tests/python").join(script)).arg(&path).current_dir(dir);
    for (k, _) in std::env::vars() {
        if k.starts_with("AWS_") || k.starts_with("AZURE_") {
            c.env_remove(k);
        }
    }
    let out = ok(c.output().unwrap(), &format!("tests/python/{script} (pointreggpt_data with torch; the viewer check needs `pip install \"./python[viewer]\"`)"));
    serde_json::from_str(out.trim().lines().last().unwrap()).unwrap()
}

/// A version-3 dataset whose targets have all three kinds of point (re-projected, seen by the scene,
/// made up by the background fill), rejected rows (`min_overlap = 0.8`) and depth maps: one synthetic
/// scene of `frames` frames, two samples each, shards of 40 units in row groups of 3 rows (uneven: 40 =
/// 13 × 3 + 1).
fn scene_config(dir: &Path, frames: usize) -> PathBuf {
    let text = synthetic_config(1, frames, 1, 2, 160, 120, 40)
        + "[validate]\nmin_overlap = 0.8\n[output]\nrow_group_rows = 3\n[inpaint]\nmethod = \"scene\"\nfallback = { method = \"background\" }\n";
    let path = dir.join("scene-config.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// Issue 50's readers (tests/python/loader_check.py): `PairDataset` + `GroupShuffleSampler` (mix 1 and
/// 2) and `StreamingPairDataset` (read-ahead threads, pieces of several row groups) give every `ok` pair
/// exactly once per epoch across 2 ranks × 2 DataLoader workers, two epochs; every pair of every reader
/// (and of `PairDataset(fields=MINIMAL_FIELDS)` in a random order) equals the in-order reader's bit for
/// bit; with the depth-PNG column chunks of every shard overwritten by garbage, reading a PNG column
/// raises while every reader still reads every pair, the same bytes (the columns it does not give are
/// not read); the shuffle buffer keeps each pair within `buffer_size` places of where it arrived; and on
/// a local S3 server (moto), whole-shard streaming, reads through local copies (`cache_dir`) and ranged
/// random reads give the same pairs, once per epoch.
#[test]
fn the_new_readers_give_every_pair_once_the_same_bytes_and_never_read_unasked_columns() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config = scene_config(dir.path(), 96);
    let ds = dir.path().join("ds");
    build(&config, ds.to_str().unwrap(), &[]);
    let shards = committed_shards(&ds);
    assert_eq!(shards, 5, "192 units in shards of 40");
    let reference = dir.path().join("reference.parquet");
    let sql = "select unit_index, pair_key, status from pairs order by unit_index";
    run(&["query", ds.to_str().unwrap(), sql, "--format", "parquet", "--output", reference.to_str().unwrap()], &[]);
    let count = run(&["query", ds.to_str().unwrap(), "select count(*) n from pairs where status = 'ok'", "--format", "json"], &[]);
    let ok_rows = serde_json::from_str::<Value>(count.trim()).unwrap()["n"].as_u64().unwrap();
    let scratch = dir.path().join("scratch");
    std::fs::create_dir(&scratch).unwrap();
    let moto = Moto::start();
    let plan = json!({"dataset": ds, "reference": reference, "scratch": scratch, "ranks": 2, "workers": 2, "buffer": 5, "s3_endpoint": moto.endpoint()});
    let report = run_script("loader_check.py", &plan, dir.path());
    assert_eq!(report["ok"], ok_rows, "{report}");
    assert!(ok_rows > 0 && ok_rows < 192, "ok and rejected rows: {report}");
    assert_eq!(report["row_groups"], 4 * 14 + 11, "row groups of 3 rows: {report}");
    for part in ["readers", "projection"] {
        for key in ["group_mix1_pairs", "group_mix2_pairs", "stream_pairs", "map_pairs"] {
            assert_eq!(report[part][key], 2 * ok_rows, "{part} {key}: two epochs (or two random passes) of every ok pair: {report}");
        }
    }
    assert_eq!(report["projection"]["png_reads_raising"], shards, "{report}");
    assert!(report["projection"]["corrupted_chunks"].as_u64().unwrap() >= 4 * 67, "every PNG chunk of every row group: {report}");
    assert!(report["buffer"]["largest_displacement"].as_u64().unwrap() <= 5, "{report}");
    for key in ["stream_whole_shards_pairs", "stream_cached_pairs", "group_cached_pairs"] {
        assert_eq!(report["s3"][key], 2 * ok_rows, "on the local S3 server, {key}: {report}");
    }
}

/// The viewer extra (tests/python/viewer_check.py): `show_pair` with no display writes an `.rrd` file;
/// read back with Rerun's own reader it holds the source cloud as stored, the target cloud in the source
/// frame split into re-projected, scene and made-up points as the stored shares say, and the depth
/// images with the PNGs' pixels.
#[test]
fn show_pair_writes_a_recording_of_both_clouds_by_provenance_and_the_depth_images() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config = scene_config(dir.path(), 48);
    let ds = dir.path().join("ds");
    build(&config, ds.to_str().unwrap(), &[]);
    let scratch = dir.path().join("scratch");
    std::fs::create_dir(&scratch).unwrap();
    let report = run_script("viewer_check.py", &json!({"dataset": ds, "scratch": scratch}), dir.path());
    for kind in ["reprojected", "scene", "made_up"] {
        assert!(report["counts"][kind].as_u64().unwrap() > 0, "{kind}: {report}");
    }
    let file = report["file"].as_str().unwrap();
    assert!(file.starts_with("pair-") && file.ends_with(".rrd"), "{report}");
    assert!(std::fs::metadata(scratch.join(file)).unwrap().len() > 0, "written in the working folder: {report}");
}
