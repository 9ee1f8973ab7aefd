#!/usr/bin/env python3
"""The training loaders of pointreggpt_data against pyarrow's own row-group loop (benchmarks/loader.sh, issue 50).

  loader_peers.py DATASET MODE [MODE...] [--limit N] [--fields all|minimal] [--storage-options JSON]
                  [--cache-dir DIR] [--mix M] [--package DIR] [--repeat R] [--piece-rows N] [--readahead N]

Prints one JSON line per mode: {"mode", "pairs", "seconds", "pairs_per_s", ...}. Every mode reads the same
pair columns (the clouds, the pose, the per-point provenance, keys and overlaps: the package's default
fields; `--fields minimal`: the two clouds and the pose) of the `ok` pairs, and makes a numpy array (or a
torch tensor) of every cloud of every pair. Modes:

  peer            pyarrow alone, in file order: for each shard pq.ParquetFile(...).read_row_group(g, columns)
                  for every row group, then each pair's clouds, pose and provenance as numpy arrays (rejected
                  rows dropped). No DataLoader, no shuffling: the floor of what Python + pyarrow cost.
  in_order        PairDataset, items 0, 1, 2, ... in unit order, in this process (no DataLoader).
  pairs           Dataset.pairs(): the whole-shard reader, in this process.
  stream_0, stream_2        StreamingPairDataset(tensors=True, shuffled) into a DataLoader, batch 8, collate,
                            0 or 2 workers.
  random_0, random_2        PairDataset(tensors=True) with a shuffled sampler (DataLoader(shuffle=True):
                            uniformly random order), batch 8, collate, 0 or 2 workers.
  group_0, group_2          the same with GroupShuffleSampler(batch_size=8, num_workers=W, mix=M), M 8 by default.

`--limit N` stops a mode after N pairs (the rate is over what was read); the DataLoader modes count the
pairs of the batches they received. `--package DIR` imports pointreggpt_data from DIR first (to time
another version of the package in the same run). `--repeat R` runs each mode R times (one line each).
"""
import argparse
import json
import sys
import time

PAIR_COLUMNS = ["unit_index", "pair_key", "scene", "status", "seed", "t_target_from_source", "source_points",
                "target_points", "overlap_source", "overlap_target", "target_known_share", "target_scene_share",
                "target_view"]
MINIMAL_COLUMNS = ["unit_index", "status", "t_target_from_source", "source_points", "target_points"]


def peer(url, storage_options, columns, limit):
    """pyarrow's own loop over the committed shards (the manifest's order), row group by row group."""
    import numpy as np
    import pyarrow.parquet as pq
    import pointreggpt_data as prd

    ds = prd.open_dataset(url, storage_options=storage_options)
    n = 0
    t = time.perf_counter()
    for shard in ds.shards:
        with ds.filesystem.open_input_file(shard.path) as f:
            pf = pq.ParquetFile(f, pre_buffer=ds.remote)
            names = pf.schema_arrow.names
            cols = [c for c in columns if c in names]
            for g in range(pf.metadata.num_row_groups):
                tab = pf.read_row_group(g, columns=cols, use_threads=False)
                ok = np.asarray(tab.column("status").to_numpy(zero_copy_only=False) == "ok")
                arrays = {}
                for c in cols:
                    col = tab.column(c).combine_chunks()
                    if c.endswith("_points"):
                        arrays[c] = (np.asarray(col.offsets), np.asarray(col.flatten().flatten().to_numpy(), np.float32).reshape(-1, 3))
                    elif c.startswith("target_") or c == "t_target_from_source":
                        arrays[c] = (np.asarray(col.offsets) if hasattr(col, "offsets") else None, np.asarray(col.flatten().to_numpy()))
                for i in np.flatnonzero(ok):
                    pair = {}
                    for c, (off, values) in arrays.items():
                        if off is None:  # the pose: 16 values per row
                            pair[c] = values[16 * i:16 * i + 16].reshape(4, 4).copy()
                        else:
                            pair[c] = values[off[i]:off[i + 1]].copy()
                    n += 1
                    if limit and n >= limit:
                        return n, time.perf_counter() - t
    return n, time.perf_counter() - t


def count_batches(loader, limit):
    n = 0
    t = time.perf_counter()
    for b in loader:
        n += len(b["unit_index"])
        if limit and n >= limit:
            break
    return n, time.perf_counter() - t


def run(mode, args, prd, torch):
    fields = None if args.fields == "all" else prd.MINIMAL_FIELDS
    opts = json.loads(args.storage_options) if args.storage_options else None
    open_ds = lambda: prd.open_dataset(args.dataset, storage_options=opts, cache_dir=args.cache_dir) if args.cache_dir \
        else prd.open_dataset(args.dataset, storage_options=opts)
    extra = {}
    if mode == "peer":
        n, s = peer(args.dataset, opts, PAIR_COLUMNS if args.fields == "all" else MINIMAL_COLUMNS, args.limit)
    elif mode == "in_order":
        kw = {} if fields is None else {"fields": fields}
        m = prd.PairDataset(open_ds(), **kw)
        t, n = time.perf_counter(), 0
        for i in range(len(m)):
            m[i]
            n += 1
            if args.limit and n >= args.limit:
                break
        s = time.perf_counter() - t
    elif mode == "pairs":
        t, n = time.perf_counter(), 0
        for _ in open_ds().pairs():
            n += 1
            if args.limit and n >= args.limit:
                break
        s = time.perf_counter() - t
    else:
        kind, workers = mode.rsplit("_", 1)
        workers = int(workers)
        kw = {} if fields is None else {"fields": fields}
        t0 = time.perf_counter()
        if kind == "stream":
            if args.piece_rows:
                kw["piece_rows"] = args.piece_rows
            if args.readahead is not None:
                kw["readahead"] = args.readahead
            data = prd.StreamingPairDataset(open_ds(), tensors=True, seed=0, **kw)
            extra["pieces"] = len(data.pieces)
            extra["readahead"] = getattr(data, "readahead", None)  # None: a package version without read-ahead
            loader = torch.utils.data.DataLoader(data, batch_size=8, collate_fn=prd.collate, num_workers=workers)
        elif kind == "random":
            data = prd.PairDataset(open_ds(), tensors=True, **kw)
            loader = torch.utils.data.DataLoader(data, batch_size=8, shuffle=True, collate_fn=prd.collate, num_workers=workers,
                                                 generator=torch.Generator().manual_seed(0))
        elif kind == "group":
            data = prd.PairDataset(open_ds(), tensors=True, cache_groups=max(16, 2 * args.mix), **kw)
            sampler = prd.GroupShuffleSampler(data, batch_size=8, num_workers=workers, mix=args.mix)
            loader = torch.utils.data.DataLoader(data, batch_size=8, sampler=sampler, collate_fn=prd.collate, num_workers=workers)
            extra["mix"] = args.mix
        else:
            raise SystemExit(f"unknown mode {mode}")
        extra["setup_s"] = round(time.perf_counter() - t0, 3)
        n, s = count_batches(loader, args.limit)
    return dict(mode=mode, pairs=n, seconds=round(s, 3), pairs_per_s=round(n / s, 1), fields=args.fields, **extra)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dataset")
    ap.add_argument("modes", nargs="+")
    ap.add_argument("--limit", type=int, default=0)
    ap.add_argument("--fields", choices=["all", "minimal"], default="all")
    ap.add_argument("--storage-options")
    ap.add_argument("--cache-dir")
    ap.add_argument("--mix", type=int, default=8)
    ap.add_argument("--package")
    ap.add_argument("--piece-rows", type=int, help="StreamingPairDataset(piece_rows=...) (default: the package's)")
    ap.add_argument("--readahead", type=int, help="StreamingPairDataset(readahead=...) (default: the package's)")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    if args.package:
        sys.path.insert(0, args.package)
    import torch
    import pointreggpt_data as prd

    for mode in args.modes:
        for _ in range(args.repeat):
            print(json.dumps(run(mode, args, prd, torch)), flush=True)


if __name__ == "__main__":
    main()
