#!/usr/bin/env python3
"""Runs SQL with DuckDB over the committed `pairs` shards of a pointreggpt dataset (the files listed in
manifest/) and prints each query's rows as one JSON line: a list of lists.

Usage: duckdb_query.py <dataset> <sql> [<sql> ...]    (the view is called `pairs`)
"""
import json
import os
import sys

import duckdb


def main():
    root, queries = sys.argv[1], sys.argv[2:]
    manifest = os.path.join(root, "manifest")
    files = []
    for name in sorted(os.listdir(manifest)):
        if name.startswith("pairs-") and name.endswith(".json"):
            with open(os.path.join(manifest, name)) as f:
                files.append(os.path.join(root, "shards", json.load(f)["file"]))
    con = duckdb.connect()
    listed = ", ".join("'" + f.replace("'", "''") + "'" for f in files)
    con.execute(f"create view pairs as select * from read_parquet([{listed}])")
    for q in queries:
        rows = con.execute(q).fetchall()
        print(json.dumps([[v for v in r] for r in rows]))


if __name__ == "__main__":
    main()
