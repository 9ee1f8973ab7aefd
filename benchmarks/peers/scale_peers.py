#!/usr/bin/env python3
"""Peers of benchmarks/scale.sh, each printing one JSON line with its seconds and what it read.

  delta DATASET                  the Delta table read by deltalake (row count, all columns but the point lists)
                                 and by Polars (pl.scan_delta: status counts)
  duckdb DATASET SQL...          each SQL over DeltaTable(DATASET).to_pyarrow_dataset() as `pairs` in DuckDB
  loaders DATASET                pointreggpt_data: PairDataset in order, in a random order (300 items),
                                 StreamingPairDataset into a DataLoader with 0 and 2 workers (batch 8, collate)
"""
import json
import random
import sys
import time


def seconds(f):
    t = time.perf_counter()
    out = f()
    return time.perf_counter() - t, out


def delta(dataset):
    import polars as pl
    from deltalake import DeltaTable

    scalar = ["unit_index", "pair_key", "status", "overlap_source", "overlap_target"]
    s, n = seconds(lambda: DeltaTable(dataset).to_pyarrow_table(columns=scalar).num_rows)
    p, counts = seconds(lambda: pl.scan_delta(dataset).group_by("status").len().collect().to_dicts())
    return {"deltalake_s": s, "deltalake_rows": n, "polars_s": p, "polars_rows": sum(c["len"] for c in counts)}


def duckdb_queries(dataset, *sqls):
    import duckdb
    from deltalake import DeltaTable

    con = duckdb.connect()
    con.register("pairs", DeltaTable(dataset).to_pyarrow_dataset())
    out = []
    for sql in sqls:
        s, rows = seconds(lambda: con.sql(sql).fetchall())
        out.append({"sql": sql, "s": s, "rows": [list(map(str, r)) for r in rows][:5]})
    return out


def rate(items, limit=None):
    t, n = time.perf_counter(), 0
    for x in items:
        n += len(x["pair_key"]) if isinstance(x["pair_key"], list) else 1
        if limit and n >= limit:
            break
    return {"pairs": n, "pairs_per_s": n / (time.perf_counter() - t)}


def loaders(dataset):
    import torch
    import pointreggpt_data as prd

    ds = prd.open_dataset(dataset)
    out = {}
    m = prd.PairDataset(ds)
    out["map_in_order"] = rate(m[i] for i in range(len(m)))
    order = list(range(len(m)))
    random.Random(1).shuffle(order)
    m = prd.PairDataset(ds)
    out["map_random"] = rate((m[i] for i in order), 300)
    for workers in (0, 2):
        stream = prd.StreamingPairDataset(ds, tensors=True, seed=0)
        loader = torch.utils.data.DataLoader(stream, batch_size=8, collate_fn=prd.collate, num_workers=workers)
        out[f"stream_{workers}_workers"] = rate(loader)
    return out


if __name__ == "__main__":
    cmd, args = sys.argv[1], sys.argv[2:]
    result = {"delta": delta, "duckdb": duckdb_queries, "loaders": loaders}[cmd](*args)
    print(json.dumps(result))
