//! `pointreggpt query` (DataFusion) against DuckDB running the same SQL over the same committed files.

use crate::support;

use pointreggpt::pipeline::{run_build, BuildConfig, BuildOptions};
use pointreggpt::runtime::CancelToken;
use std::path::Path;
use crate::support::{bin, synthetic_config};

fn dataset(dir: &Path) -> std::path::PathBuf {
    let text = synthetic_config(2, 16, 2, 1, 320, 240, 3) + "[validate]\nmin_overlap = 0.6\n";
    let config = BuildConfig::from_toml(&text, "t").unwrap();
    let out = dir.join("ds");
    let opts = BuildOptions::into_folder(out.clone());
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
    let _timing = crate::support::timed();
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
    let py = support::python_command().arg(&script).arg(&ds).args(queries).output().unwrap();
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
    let _timing = crate::support::timed();
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

/// Checks our JSON and CSV files against DuckDB reading the committed shards themselves (argv: dataset,
/// json file, csv file): strict JSON, the documented NaN/inf forms, lists and binary intact.
const CHECK_FORMATS_PY: &str = r#"
import json, math, os, struct, sys
import duckdb, pyarrow.csv as pc

root, json_path, csv_path = sys.argv[1:4]
files = []
for name in sorted(os.listdir(os.path.join(root, "manifest"))):
    if name.startswith("pairs-") and name.endswith(".json"):
        with open(os.path.join(root, "manifest", name)) as f:
            files.append(os.path.join(root, "shards", json.load(f)["file"]))
con = duckdb.connect()
listed = ", ".join("'" + f.replace("'", "''") + "'" for f in files)
ref = con.execute(f"select unit_index, overlap_source, source_points, source_depth_png from read_parquet([{listed}]) order by unit_index limit 5").fetchall()
assert len(ref) == 5, ref

f32 = lambda v: struct.unpack("f", struct.pack("f", v))[0]
def same_points(ours, theirs, what):
    assert len(ours) == len(theirs) > 0, (what, len(ours), len(theirs))
    for p, q in zip(ours, theirs):
        assert len(p) == 3 and all(f32(a) == b for a, b in zip(p, q)), (what, p, q)

def no_constants(c):
    raise ValueError("not strict JSON: " + c)

columns = ["r", "x", "unit_index", "ov", "source_points", "png", "b", "l"]
with open(json_path) as f:
    rows = [json.loads(line, parse_constant=no_constants) for line in f]
assert len(rows) == 5, len(rows)
for i, (row, (unit, ov, points, png)) in enumerate(zip(rows, ref)):
    assert list(row) == columns, list(row)
    assert row["r"] == i + 1 and row["unit_index"] == unit and row["ov"] == ov, (row["r"], row["unit_index"], row["ov"], unit, ov)
    assert row["x"] == (2.5 if i == 4 else None), ("json x", i, row["x"])
    same_points(row["source_points"], points, "json")
    assert row["png"] == png.hex() and row["b"] == "00ff61" and row["l"] == [1.5, None, None], (row["b"], row["l"])

got = con.execute(f"select * from read_csv('{csv_path}', header = true)").fetchall()
names = [d[0] for d in con.description]
assert names == columns, names
assert len(got) == 5, len(got)
for i, (row, (unit, ov, points, png)) in enumerate(zip(got, ref)):
    r, x, u, o, pts, hx, b, l = row
    assert (r, u, o) == (i + 1, unit, ov), (row[:4], unit, ov)
    expect = [math.nan, math.inf, -math.inf, None, 2.5][i]
    assert (x is None) == (expect is None) and (expect is None or (math.isnan(x) and math.isnan(expect)) or x == expect), ("csv x", i, x)
    same_points(json.loads(pts), points, "csv")
    assert hx == png.hex() and b == "00ff61" and json.loads(l) == [1.5, None, None], (b, l)

opts = pc.ConvertOptions(null_values=[""], column_types={"x": "float64"})
xs = pc.read_csv(csv_path, convert_options=opts).column("x").to_pylist()
assert [str(v) for v in xs] == ["nan", "inf", "-inf", "None", "2.5"], xs
print("ok", len(rows))
"#;

#[test]
fn nan_inf_null_lists_and_binary_in_every_text_format() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let ds = dataset(dir.path());
    let sql = "select r, \
               case r when 1 then cast('NaN' as double) when 2 then 1.0 / 0.0 when 3 then -1.0 / 0.0 \
               when 4 then null else 2.5 end as x, \
               unit_index, overlap_source as ov, source_points, source_depth_png as png, X'00ff61' as b, \
               make_array(1.5, cast('NaN' as double), cast('-inf' as double)) as l \
               from (select row_number() over (order by unit_index) as r, * from pairs) where r <= 5 order by r";
    let write = |format: &str| {
        let path = dir.path().join(format!("out.{format}"));
        let mut query = bin();
        let o = query.args(["query"]).arg(&ds).args([sql, "--format", format, "--output"]).arg(&path).output().unwrap();
        assert!(o.status.success(), "--format {format}: {}", String::from_utf8_lossy(&o.stderr));
        path
    };
    let (json, csv, table) = (write("json"), write("csv"), write("table"));

    let mut check = support::python_command();
    let py = check.arg("-c").arg(CHECK_FORMATS_PY).arg(&ds).args([&json, &csv]).output().unwrap();
    assert!(py.status.success(), "run scripts/install-test-deps.sh: {}", String::from_utf8_lossy(&py.stderr));
    assert_eq!(String::from_utf8_lossy(&py.stdout).trim(), "ok 5");

    // The table: the header names every column, one line per row, the count, wide cells cut.
    let table = std::fs::read_to_string(table).unwrap();
    let lines: Vec<&str> = table.lines().collect();
    let header: Vec<&str> = lines[1].split('|').map(str::trim).filter(|c| !c.is_empty()).collect();
    assert_eq!(header, ["r", "x", "unit_index", "ov", "source_points", "png", "b", "l"], "{table}");
    let rows: Vec<Vec<&str>> =
        lines[3..].iter().filter(|l| l.starts_with('|')).map(|l| l.split('|').map(str::trim).collect()).collect();
    assert_eq!(rows.len(), 5, "{table}");
    assert_eq!(rows.iter().map(|r| r[2]).collect::<Vec<_>>(), ["NaN", "inf", "-inf", "NULL", "2.5"]);
    assert_eq!(lines.last(), Some(&"(5 rows)"));
    for r in &rows {
        assert!(r[5].ends_with('…') && r[5].chars().count() == 60 && r[6].ends_with('…'), "{r:?}");
        assert_eq!((r[7], r[8]), ("00ff61", "[1.5, NaN, -inf]"));
    }
}
