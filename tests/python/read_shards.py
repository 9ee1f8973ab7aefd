#!/usr/bin/env python3
"""Reads the committed `pairs` shards of a pointreggpt dataset with pyarrow and with DuckDB.

Usage: read_shards.py <dataset>

Only shards listed in <dataset>/manifest/ are read (the commit protocol: a shard file without a manifest
entry does not exist). Prints one JSON object: for each reader ("pyarrow", "duckdb") the row count, rows per
status, the sum of len(source_points) and len(target_points), the mean overlap_source, and the rows with
overlap_source >= 0.4; plus the schema_version of every file (pyarrow) and the files read.
Run by tests/shards.rs; install the modules with scripts/install-test-deps.sh.
"""
import json
import os
import sys

import duckdb
import pyarrow as pa
import pyarrow.parquet as pq


def committed_files(root):
    """The shard files of the `pairs` table named by the manifest entries, sorted by shard."""
    manifest = os.path.join(root, "manifest")
    entries = []
    for name in sorted(os.listdir(manifest)):
        if not (name.startswith("pairs-") and name.endswith(".json")):
            continue
        with open(os.path.join(manifest, name)) as f:
            entry = json.load(f)
        entries.append(entry)
    entries.sort(key=lambda e: e["shard"])
    return [os.path.join(root, "shards", e["file"]) for e in entries]


def with_pyarrow(files):
    tables = [pq.read_table(f) for f in files]
    versions = sorted({(t.schema.metadata or {}).get(b"schema_version", b"").decode() for t in tables})
    table = pa.concat_tables(tables)
    status = table.column("status").to_pylist()
    counts = {s: status.count(s) for s in sorted(set(status))}
    points = table.column("source_points").to_pylist()
    target = table.column("target_points").to_pylist()
    overlap = table.column("overlap_source").to_pylist()
    result = {
        "rows": table.num_rows,
        "rows_by_status": counts,
        "source_points": sum(len(p) for p in points),
        "target_points": sum(len(p) for p in target),
        "mean_overlap_source": sum(overlap) / len(overlap) if overlap else None,
        "overlap_at_least_0_4": sum(1 for v in overlap if v >= 0.4),
    }
    return result, versions


def with_duckdb(files):
    listing = ", ".join("'" + f.replace("'", "''") + "'" for f in files)
    source = f"read_parquet([{listing}])"
    rows, points, target, mean, high = duckdb.sql(
        "select count(*), sum(len(source_points)), sum(len(target_points)), avg(overlap_source), "
        f"count(*) filter (where overlap_source >= 0.4) from {source}"
    ).fetchall()[0]
    counts = dict(duckdb.sql(f"select status, count(*) from {source} group by status order by status").fetchall())
    return {
        "rows": rows,
        "rows_by_status": counts,
        "source_points": int(points or 0),
        "target_points": int(target or 0),
        "mean_overlap_source": mean,
        "overlap_at_least_0_4": high,
    }


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: read_shards.py <dataset>")
    files = committed_files(sys.argv[1])
    if not files:
        sys.exit("read_shards.py: no committed pairs shard in " + sys.argv[1])
    arrow_result, versions = with_pyarrow(files)
    print(json.dumps({
        "files": [os.path.basename(f) for f in files],
        "schema_versions": versions,
        "pyarrow": arrow_result,
        "duckdb": with_duckdb(files),
        "versions": {"pyarrow": pa.__version__, "duckdb": duckdb.__version__},
    }))


if __name__ == "__main__":
    main()
