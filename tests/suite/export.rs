//! `export`, `preview` and `stats` end to end on a small synthetic dataset: every export format read
//! back (Rust readers and Python: numpy PLY parser, pickle, GeoTransformer's torch.load of the .pth clouds,
//! np.load), ground-truth alignment, the
//! official gt.log keep rule, SQL `--where`/`--limit` against rows filtered in Rust and DuckDB, `stats`
//! counts against the same, PNG outputs, and the pyarrow `PairDataset` of tests/python/pair_dataset.py.

use crate::support;

use pointreggpt::export::npy::read_npy_points;
use pointreggpt::export::pth::encode_pth_points;
use pointreggpt::export::pointreggpt::official_keep;
use pointreggpt::export::PairWriter;
use pointreggpt::geometry::Point;
use pointreggpt::geometry::{pose_from_rows, transform_points};
use pointreggpt::pipeline::{run_build, BuildConfig, BuildOptions};
use pointreggpt::preview::montage_size;
use pointreggpt::preview::stats::{overlap_bin, PLOT_SIZE, STATUSES};
use pointreggpt::runtime::CancelToken;
use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::row::{PairRow, Status};
use serde_json::json;
use std::path::{Path, PathBuf};
use pointreggpt::ply::read_ply;
use crate::support::{bin, synthetic_config};

/// 2 scenes × 4 frames, one sample each, shards of 4; `min_overlap = 0.6` rejects some pairs, so the
/// dataset holds `ok` and `low_overlap` rows.
fn build(dir: &Path) -> (PathBuf, Vec<PairRow>) {
    let text = synthetic_config(2, 12, 3, 1, 320, 240, 4) + "[validate]\nmin_overlap = 0.6\n";
    let config = BuildConfig::from_toml(&text, "test").unwrap();
    let out = dir.join("ds");
    let opts = BuildOptions::into_folder(out.clone());
    run_build(&config, &opts, &CancelToken::new()).unwrap();
    let rows = Dataset::open(&out).unwrap().read_pairs().unwrap();
    assert_eq!(rows.len(), 8);
    let ok = rows.iter().filter(|r| r.status == Status::Ok).count();
    assert!((3..8).contains(&ok), "the test wants both ok and rejected rows, got {ok} ok");
    (out, rows)
}

/// Runs the binary; returns (success, stdout, stderr).
fn run(args: &[&str]) -> (bool, String, String) {
    let o = bin().args(args).arg("--no-progress").output().unwrap();
    (o.status.success(), String::from_utf8_lossy(&o.stdout).into_owned(), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn export(ds: &Path, format: &str, out: &Path, extra: &[&str]) -> String {
    let mut args = vec!["export", ds.to_str().unwrap(), "--format", format, "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    let (ok, stdout, stderr) = run(&args);
    assert!(ok, "export {format} failed: {stderr}");
    stdout
}

/// The pair keys listed in an export's `metadata/pairs.tsv`.
fn exported_keys(out: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(out.join("metadata/pairs.tsv")).unwrap();
    text.lines().skip(1).map(|l| l.split('\t').nth(1).unwrap().to_string()).collect()
}

fn keys<'a>(rows: impl IntoIterator<Item = &'a PairRow>) -> Vec<String> {
    rows.into_iter().map(|r| r.pair_key.clone()).collect()
}

fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python").join(name)
}

#[test]
fn every_format_reads_back_and_agrees_with_the_rows() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (ds, rows) = build(dir.path());
    let ok: Vec<&PairRow> = rows.iter().filter(|r| r.status == Status::Ok).collect();
    let (official, geo, ply) = (dir.path().join("official"), dir.path().join("geo"), dir.path().join("ply"));
    let line = export(&ds, "pointreggpt", &official, &[]);
    assert!(line.contains(&format!("wrote {} pairs (pointreggpt format)", ok.len())), "{line}");
    assert!(line.contains(&format!("{} matching rows not ok, skipped", rows.len() - ok.len())), "{line}");
    export(&ds, "geotransformer", &geo, &[]);
    let geo_npy = dir.path().join("geo-npy");
    export(&ds, "geotransformer", &geo_npy, &["--cloud-format", "npy"]);
    export(&ds, "ply", &ply, &[]);

    // The authors' layout, read with our own readers.
    assert_eq!(exported_keys(&official), keys(ok.iter().copied()));
    let gt = std::fs::read_to_string(official.join("metadata/gt.log")).unwrap();
    let mut want_gt = String::new();
    for (k, r) in ok.iter().enumerate() {
        let d = official.join(format!("data/scene-{k:06}"));
        assert_eq!(read_ply(&d.join("sample-000000.cloud.ply")).unwrap(), r.source_points);
        let pose = pose_from_rows(&r.t_target_from_source).unwrap();
        let back = transform_points(&read_ply(&d.join("sample-000001.cloud.ply")).unwrap(), &pose);
        let err = back.iter().zip(&r.target_points).map(|(a, b)| (a - b).norm()).fold(0.0f32, f32::max);
        assert!(err < 1e-5, "target cloud is inv(T)·target: {err}");
        if official_keep(r) {
            want_gt += &format!("scene-{k:06}\t0\t1\t{:.4}\t{:.4}\n", r.overlap_source, r.overlap_target);
        }
    }
    assert_eq!(gt, want_gt);
    assert!(!gt.is_empty());

    // GeoTransformer's .pth clouds (default) and .npy clouds (--cloud-format npy), and PLY pairs (every
    // row, rejected ones too).
    for (k, r) in ok.iter().enumerate() {
        let d = geo_npy.join("data/train").join(&r.scene);
        assert_eq!(read_npy_points(&d.join(format!("cloud_bin_{}.npy", 2 * k))).unwrap(), r.target_points);
        assert_eq!(read_npy_points(&d.join(format!("cloud_bin_{}.npy", 2 * k + 1))).unwrap(), r.source_points);
        let d = geo.join("data/train").join(&r.scene);
        for (i, cloud) in [(2 * k, &r.target_points), (2 * k + 1, &r.source_points)] {
            let name = format!("cloud_bin_{i}");
            assert_eq!(std::fs::read(d.join(format!("{name}.pth"))).unwrap(), encode_pth_points(&name, cloud));
            assert!(!d.join(format!("{name}.npy")).exists());
        }
    }
    let (ok_flag, _, stderr) = run(&["export", ds.to_str().unwrap(), "--format", "ply", "--cloud-format", "npy", "--out", dir.path().join("x").to_str().unwrap()]);
    assert!(!ok_flag && stderr.contains("--cloud-format"), "{stderr}");
    assert_eq!(exported_keys(&ply), keys(&rows));
    for r in &rows {
        let d = ply.join(r.pair_key.replace(['/', '#'], "_"));
        assert_eq!(read_ply(&d.join("source.ply")).unwrap(), r.source_points);
        assert_eq!(read_ply(&d.join("target.ply")).unwrap(), r.target_points);
    }

    // Python: numpy PLY parser, np.loadtxt, pickle.load, np.load and the alignment check.
    let plan = json!({
        "pointreggpt": official, "geotransformer": geo, "geotransformer_npy": geo_npy, "ply": ply,
        "exported": keys(ok.iter().copied()), "ply_exported": keys(&rows),
    });
    let plan_path = dir.path().join("plan.json");
    std::fs::write(&plan_path, plan.to_string()).unwrap();
    let o = support::python_command().arg(script("check_exports.py")).arg(&ds).arg(&plan_path).output().unwrap();
    assert!(o.status.success(), "check_exports.py failed (numpy, pyarrow and torch are required: scripts/install-test-deps.sh):\n{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["pointreggpt"]["scenes"], ok.len());
    for geo in ["geotransformer", "geotransformer_npy"] {
        assert_eq!(v[geo]["entries"], ok.len(), "{v}");
        assert_eq!(v[geo]["overlaps_bit_exact"], ok.len(), "{v}");
    }
    // torch.load read every .pth cloud; the files compared with torch.save's record by record; torch's
    // default weights_only=True refuses them (as GeoTransformer's own files), the documented allow-list not.
    assert_eq!(v["geotransformer"]["clouds"], "pth");
    assert_eq!(v["geotransformer"]["compared_with_torch_save"], 2 * ok.len().min(2), "{v}");
    assert_eq!(v["geotransformer"]["pickle_module"], "numpy.core.multiarray", "{v}");
    assert_eq!(v["geotransformer"]["weights_only_default_refuses"], true, "{v}");
    assert_eq!(v["ply"]["pairs"], rows.len());
}

/// DuckDB's rows for each query, over the same committed shard files (tests/python/duckdb_query.py).
fn duckdb(ds: &Path, queries: &[String]) -> Vec<serde_json::Value> {
    let o = support::python_command().arg(script("duckdb_query.py")).arg(ds).args(queries).output().unwrap();
    assert!(o.status.success(), "duckdb_query.py failed (duckdb is required: scripts/install-test-deps.sh):\n{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

/// The pair keys DuckDB selects with `predicate`, in unit order.
fn duckdb_keys(ds: &Path, predicates: &[String]) -> Vec<Vec<String>> {
    // The predicate on lines of its own, so a trailing `--` comment ends there.
    let queries: Vec<String> = predicates.iter().map(|p| format!("select pair_key from pairs where (\n{p}\n) order by unit_index")).collect();
    let rows = duckdb(ds, &queries);
    rows.iter().map(|r| r.as_array().unwrap().iter().map(|k| k[0].as_str().unwrap().to_string()).collect()).collect()
}

#[test]
fn where_and_limit_select_exactly_the_rows_filtered_in_rust_and_duckdb() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (ds, rows) = build(dir.path());
    let mut counts: Vec<usize> = rows.iter().map(|r| r.target_points.len()).collect();
    counts.sort();
    let median = counts[counts.len() / 2];
    type Predicate = Box<dyn Fn(&PairRow) -> bool>;
    let like = |k: &str| k.strip_prefix("synthetic-1/frame-00000").is_some_and(|t| t.chars().count() == 3 && t.ends_with("#0"));
    let cases: Vec<(String, Predicate)> = vec![
        ("status = 'ok' and overlap_source >= 0.6".into(), Box::new(|r| r.status == Status::Ok && r.overlap_source >= 0.6)),
        ("scene = 'synthetic-1' or status <> 'ok'".into(), Box::new(|r| r.scene == "synthetic-1" || r.status != Status::Ok)),
        ("(unit_index < 3 or unit_index >= 6) and array_length(source_points) > 1000".into(), Box::new(|r| (r.unit_index < 3 || r.unit_index >= 6) && r.source_points.len() > 1000)),
        ("overlap_target <= 0.75 AND frame_key != 'synthetic-0/frame-000000'".into(), Box::new(|r| r.overlap_target <= 0.75 && r.frame_key != "synthetic-0/frame-000000")),
        ("scene in ('synthetic-0', 'elsewhere') and not status = 'ok'".into(), Box::new(|r| r.scene == "synthetic-0" && r.status != Status::Ok)),
        ("pair_key like 'synthetic-1/frame-00000_#0' and unit_index not in (4, 7)".into(), Box::new(move |r| like(&r.pair_key) && ![4, 7].contains(&r.unit_index))),
        ("not (status = 'ok' or pairs.scene = 'synthetic-0')".into(), Box::new(|r| !(r.status == Status::Ok || r.scene == "synthetic-0"))),
        (format!("array_length(target_points) < {median}"), Box::new(move |r| r.target_points.len() < median)),
        ("status = 'low_overlap'".into(), Box::new(|r| r.status == Status::LowOverlap)),
        ("pair_key = 'nothing#0' -- no such pair".into(), Box::new(|_| false)),
    ];
    let in_duckdb = duckdb_keys(&ds, &cases.iter().map(|(p, _)| p.clone()).collect::<Vec<_>>());
    for (i, (predicate, f)) in cases.iter().enumerate() {
        let want = keys(rows.iter().filter(|r| f(r)));
        assert_eq!(in_duckdb[i], want, "duckdb where {predicate}");
        let out = dir.path().join(format!("ply{i}"));
        export(&ds, "ply", &out, &["--where", predicate]);
        assert_eq!(exported_keys(&out), want, "ply --where {predicate}");
        let out = dir.path().join(format!("official{i}"));
        export(&ds, "pointreggpt", &out, &["--where", predicate]);
        let want = keys(rows.iter().filter(|r| f(r) && r.status == Status::Ok));
        assert_eq!(exported_keys(&out), want, "pointreggpt --where {predicate}");
        let scenes = std::fs::read_dir(out.join("data")).map(|d| d.count()).unwrap_or(0);
        assert_eq!(scenes, want.len());
    }
    let small = rows.iter().filter(|r| r.target_points.len() < median).count();
    assert!(small > 0 && small < rows.len(), "the array_length case selects some rows, not all");
    for limit in [0usize, 1, 3, 100] {
        let out = dir.path().join(format!("limit{limit}"));
        let line = export(&ds, "geotransformer", &out, &["--limit", &limit.to_string()]);
        let want = keys(rows.iter().filter(|r| r.status == Status::Ok).take(limit));
        assert_eq!(exported_keys(&out), want, "--limit {limit}");
        assert!(line.contains(&format!("wrote {} pairs", want.len())), "{line}");
    }
    let out = dir.path().join("where-limit");
    export(&ds, "ply", &out, &["--where", "status <> 'ok' or scene = 'synthetic-1'", "--limit", "2"]);
    assert_eq!(exported_keys(&out), keys(rows.iter().filter(|r| r.status != Status::Ok || r.scene == "synthetic-1").take(2)));
}

#[test]
fn a_bad_where_fails_naming_the_column_or_the_problem() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (ds, _) = build(dir.path());
    let ds = ds.to_str().unwrap();
    let out = dir.path().join("x");
    let out = out.to_str().unwrap();
    for (predicate, needle) in [
        ("overlap >= 0.3", "unknown column `overlap`"),
        ("status = 'ok' and scen = 'a'", "unknown column `scen`"),
        ("status = ok", "unknown column `ok`"),
        ("n_source_points > 1000", "array_length(source_points)"),
        ("overlap_source >= 'high'", "Cannot cast string 'high'"),
        ("overlap_source >= 0.3 and", "not a SQL expression"),
        ("overlap_source * 2", "not true/false"),
    ] {
        for command in ["export", "preview", "stats"] {
            let mut args = vec![command, ds, "--out", out, "--where", predicate];
            if command == "export" {
                args.extend(["--format", "ply"]);
            }
            let (ok, _, stderr) = run(&args);
            assert!(!ok, "{command} --where {predicate} should fail");
            assert!(stderr.contains("--where") && stderr.contains(needle), "{command} --where {predicate}: {stderr}");
        }
    }
    assert!(!Path::new(out).exists(), "nothing is written when the predicate is bad");
    // An export never mixes with an old one.
    export(Path::new(ds), "ply", Path::new(out), &["--limit", "1"]);
    let (ok, _, stderr) = run(&["export", ds, "--format", "ply", "--out", out]);
    assert!(!ok && stderr.contains("not empty"), "{stderr}");
}

/// Width, height and colour type of a PNG file.
fn png_info(path: &Path) -> (u32, u32, png::ColorType) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0u8; reader.output_buffer_size().unwrap()];
    let frame = reader.next_frame(&mut buf).unwrap();
    (frame.width, frame.height, frame.color_type)
}

#[test]
fn previews_decode_with_the_expected_size_and_names() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (ds, rows) = build(dir.path());
    let out = dir.path().join("pv");
    let (ok, stdout, stderr) = run(&["preview", ds.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("wrote 8 preview PNGs"), "{stdout}");
    let (w, h) = montage_size(rows[0].width, rows[0].height);
    for r in &rows {
        let path = out.join(format!("{}.png", r.pair_key.replace(['/', '#'], "_")));
        assert_eq!(png_info(&path), (w, h, png::ColorType::Rgb), "{}", path.display());
    }
    let out = dir.path().join("pv2");
    let (ok, _, stderr) = run(&["preview", ds.to_str().unwrap(), "--out", out.to_str().unwrap(), "--where", "status != 'ok'", "--limit", "1"]);
    assert!(ok, "{stderr}");
    let files: Vec<_> = std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    let first_rejected = rows.iter().find(|r| r.status != Status::Ok).unwrap();
    assert_eq!(files, vec![format!("{}.png", first_rejected.pair_key.replace(['/', '#'], "_"))]);
}

#[test]
fn stats_counts_equal_the_rows_by_status_and_bins() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (ds, rows) = build(dir.path());
    type Predicate = fn(&PairRow) -> bool;
    let cases: [(Option<&str>, Predicate); 3] = [
        (None, |_| true),
        (Some("scene = 'synthetic-1' or overlap_target < 0.7"), |r| r.scene == "synthetic-1" || r.overlap_target < 0.7),
        (Some("array_length(source_points) > 0 and not unit_index in (0, 5)"), |r| !r.source_points.is_empty() && ![0, 5].contains(&r.unit_index)),
    ];
    let predicates: Vec<String> = cases.iter().map(|(p, _)| p.unwrap_or("true").to_string()).collect();
    let queries: Vec<String> = predicates.iter().map(|p| format!("select status, count(*) from pairs where (\n{p}\n) group by status")).collect();
    let in_duckdb = duckdb(&ds, &queries);
    for (i, (predicate, f)) in cases.iter().enumerate() {
        let selected: Vec<&PairRow> = rows.iter().filter(|r| f(r)).collect();
        let out = dir.path().join(format!("st{i}"));
        let mut args = vec!["stats", ds.to_str().unwrap(), "--out", out.to_str().unwrap(), "--per-scene"];
        if let Some(p) = predicate {
            args.extend(["--where", p]);
        }
        let (ok, stdout, stderr) = run(&args);
        assert!(ok, "{stderr}");
        let text = std::fs::read_to_string(out.join("stats.txt")).unwrap();
        assert!(stdout.starts_with(&text), "stdout repeats stats.txt");
        let value = |label: &str, col: usize| -> u64 {
            let line = text.lines().find(|l| l.split_whitespace().next() == Some(label) || l.starts_with(label)).unwrap_or_else(|| panic!("no line {label}"));
            line[label.len()..].split_whitespace().nth(col).unwrap().parse().unwrap()
        };
        // Rows by status: the rows read back and filtered in Rust, and DuckDB over the same files.
        let duck: Vec<(String, u64)> = in_duckdb[i].as_array().unwrap().iter().map(|r| (r[0].as_str().unwrap().into(), r[1].as_u64().unwrap())).collect();
        for st in STATUSES {
            let n = selected.iter().filter(|r| r.status == st).count() as u64;
            assert_eq!(value(st.as_str(), 0), n, "{} where {predicate:?}", st.as_str());
            let d = duck.iter().find(|(s, _)| s == st.as_str()).map_or(0, |(_, n)| *n);
            assert_eq!(d, n, "duckdb {} where {predicate:?}", st.as_str());
        }
        assert_eq!(value("total", 0), selected.len() as u64);
        let ok = || selected.iter().filter(|r| r.status == Status::Ok);
        for b in 0..10 {
            let label = format!("[{:.1}, {:.1}{}", b as f64 / 10.0, (b + 1) as f64 / 10.0, if b == 9 { "]" } else { ")" });
            assert_eq!(value(&label, 0), ok().filter(|r| overlap_bin(r.overlap_source) == b).count() as u64, "{label}");
            assert_eq!(value(&label, 1), ok().filter(|r| overlap_bin(r.overlap_target) == b).count() as u64, "{label}");
        }
        // Per scene: the rows by status, then `source/target` per bin.
        for scene in ["synthetic-0", "synthetic-1"] {
            let lines: Vec<&str> = text.lines().filter(|l| l.split_whitespace().next() == Some(scene)).collect();
            let in_scene = || selected.iter().filter(|r| r.scene == scene);
            if in_scene().count() == 0 {
                assert!(lines.is_empty(), "{scene} has no selected rows: {text}");
                continue;
            }
            let counts: Vec<u64> = lines[0].split_whitespace().skip(1).map(|v| v.parse().unwrap()).collect();
            let want: Vec<u64> = STATUSES.iter().map(|s| in_scene().filter(|r| r.status == *s).count() as u64).collect();
            assert_eq!(counts[..4], want[..], "{scene}");
            let bins: Vec<&str> = lines[1].split_whitespace().skip(1).collect();
            let want: Vec<String> = (0..10)
                .map(|b| {
                    let ok = || in_scene().filter(|r| r.status == Status::Ok);
                    let n = |g: fn(&PairRow) -> f64| ok().filter(|r| overlap_bin(g(r)) == b).count();
                    format!("{}/{}", n(|r| r.overlap_source), n(|r| r.overlap_target))
                })
                .collect();
            assert_eq!(bins, want, "{scene} bins where {predicate:?}");
        }
        assert_eq!(png_info(&out.join("stats.png")), (PLOT_SIZE.0, PLOT_SIZE.1, png::ColorType::Rgb));
    }
}

#[test]
fn pair_dataset_py_reads_only_the_committed_shards() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (ds, rows) = build(dir.path());
    // A shard file without a manifest entry is not part of the dataset.
    std::fs::copy(ds.join("shards/pairs-000000.parquet"), ds.join("shards/pairs-000099.parquet")).unwrap();
    let f = |p: &pointreggpt::geometry::Point| vec![p.x as f64, p.y as f64, p.z as f64];
    let sum = |c: &[pointreggpt::geometry::Point]| c.iter().fold([0.0f64; 3], |a, p| [a[0] + p.x as f64, a[1] + p.y as f64, a[2] + p.z as f64]);
    let expected: Vec<serde_json::Value> = rows
        .iter()
        .filter(|r| r.status == Status::Ok)
        .map(|r| {
            json!({
                "pair_key": r.pair_key, "unit_index": r.unit_index,
                "n_source": r.source_points.len(), "n_target": r.target_points.len(), "t": r.t_target_from_source.to_vec(),
                "source_first": f(&r.source_points[0]), "source_last": f(r.source_points.last().unwrap()),
                "target_first": f(&r.target_points[0]), "target_last": f(r.target_points.last().unwrap()),
                "source_sum": sum(&r.source_points), "target_sum": sum(&r.target_points),
            })
        })
        .collect();
    let path = dir.path().join("expected.json");
    std::fs::write(&path, serde_json::Value::Array(expected.clone()).to_string()).unwrap();
    let o = support::python_command().arg(script("pair_dataset.py")).arg(&ds).arg(&path).output().unwrap();
    assert!(o.status.success(), "pair_dataset.py failed (numpy and pyarrow are required: scripts/install-test-deps.sh):\n{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["pairs"], expected.len());
    assert_eq!(v["files"], 2);
}

/// An `ok` row of pair `s/frame-000000#0` with empty clouds, the identity pose and fx = fy = cx = cy = 2.
fn empty_row() -> PairRow {
    PairRow { pair_key: "s/frame-000000#0".into(), source_intrinsics: [2.0; 4], target_intrinsics: [2.0; 4], ..PairRow::default() }
}

#[test]
fn the_ply_writer_writes_both_clouds_and_the_exact_matrix() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let mut row = empty_row();
    row.source_points = vec![Point::new(1.0, 2.0, 3.0)];
    row.t_target_from_source[3] = 0.1;
    let mut w = pointreggpt::export::ply::PlyWriter::new(dir.path());
    w.write(0, &row).unwrap();
    w.finish().unwrap();
    let d = dir.path().join("s_frame-000000_0");
    assert_eq!(read_ply(&d.join("source.ply")).unwrap(), row.source_points);
    assert!(read_ply(&d.join("target.ply")).unwrap().is_empty());
    let nums: Vec<f64> = std::fs::read_to_string(d.join("T_target_from_source.txt")).unwrap().split_whitespace().map(|s| s.parse().unwrap()).collect();
    assert_eq!(nums, row.t_target_from_source.to_vec());
}

#[test]
fn the_authors_layout_puts_both_clouds_in_the_source_frame_and_gt_log_follows_the_keep_rule() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let pose = nalgebra::Isometry3::new(nalgebra::Vector3::new(0.1, -0.2, 0.3), nalgebra::Vector3::new(0.05, 0.1, -0.02));
    let src: Vec<Point> = (0..1200).map(|i| Point::new(i as f32 * 1e-3, 0.5, 2.0)).collect();
    let mut row = empty_row();
    row.t_target_from_source = pointreggpt::geometry::pose_to_rows(&pose);
    row.target_points = transform_points(&src, &pose);
    row.source_points = src.clone();
    (row.overlap_source, row.overlap_target) = (0.05, 0.123456);
    let mut w = pointreggpt::export::pointreggpt::PointRegGptWriter::new(dir.path());
    w.write(0, &row).unwrap();
    row.target_points.truncate(999);
    w.write(1, &row).unwrap();
    assert_eq!(w.finish().unwrap(), Some(1));
    let gt = std::fs::read_to_string(dir.path().join("metadata/gt.log")).unwrap();
    assert_eq!(gt, "scene-000000\t0\t1\t0.0500\t0.1235\n");
    let d = dir.path().join("data/scene-000000");
    let tgt = read_ply(&d.join("sample-000001.cloud.ply")).unwrap();
    let err = src.iter().zip(&tgt).map(|(a, b)| (a - b).norm()).fold(0.0f32, f32::max);
    assert!(err < 1e-5, "target moved back into the source frame: {err}");
    let nums: Vec<f64> = std::fs::read_to_string(d.join("sample-000001.pose.txt")).unwrap().split_whitespace().map(|s| s.parse().unwrap()).collect();
    let back = pose_from_rows(&nums.try_into().unwrap()).unwrap();
    assert!((back.to_homogeneous() - pose.inverse().to_homogeneous()).abs().max() < 1e-12);
    let k = std::fs::read_to_string(d.join("camera-intrinsics.txt")).unwrap();
    assert_eq!(k.lines().count(), 3);
    assert!(k.starts_with("2.000000000000000000e+00 0.000000000000000000e+00 2.000000000000000000e+00\n"));
}
