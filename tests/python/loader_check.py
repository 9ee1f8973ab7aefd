#!/usr/bin/env python3
"""Checks the training readers of `pointreggpt_data` that issue 50 added, on a dataset with small row
groups and rejected rows (built by tests/python_package.rs). Run by tests/python_package.rs.

Usage: loader_check.py <plan.json>

plan.json:
  dataset        a folder (a version-3 dataset whose shards hold several row groups of uneven sizes)
  reference      a Parquet file of `pointreggpt query "select unit_index, pair_key, status ... order by
                 unit_index"`: the keys every reader must give (the ok rows)
  scratch        a folder for the corrupted copy of the dataset
  ranks, workers distributed ranks (simulated: rank=, world_size=) x DataLoader workers
  buffer         the shuffle buffer bound to check
  s3_endpoint    (optional) a local S3 server (moto): the dataset is uploaded there and checks 1-2 repeated
                 for whole-shard streaming, reads through local copies (cache_dir=) and ranged random reads

Checks, each an assertion (the script fails, never skips):
  1. every ok pair exactly once per epoch, two epochs, across ranks x DataLoader workers, for
     PairDataset + GroupShuffleSampler (mix 1 and 2) and StreamingPairDataset (read-ahead threads, pieces
     of several row groups); the orders differ between epochs;
  2. every pair of those readers, and of PairDataset(fields=MINIMAL_FIELDS) and the S3-less cached-footer
     path, equals the in-order reader's (Dataset.pairs) bit for bit, field by field;
  3. projection: in a copy of the dataset whose depth-PNG column chunks are overwritten with garbage,
     reading a PNG column raises, while every reader above reads every pair without raising, and the
     same bytes;
  4. the shuffle buffer's bound: an item that arrived a-th leaves o-th with |o - a| <= B, for
     bounded_shuffle alone and inside StreamingPairDataset, and it does shuffle.
Prints one JSON object.
"""
import json
import os
import random
import shutil
import sys

import numpy as np
import pyarrow.parquet as pq
import torch

import pointreggpt_data as prd
from pointreggpt_data.training import bounded_shuffle

PNG_COLUMNS = ["source_depth_png", "condition_depth_png", "target_depth_png", "known_mask_png"]


def same(a, b):
    """Equal values, arrays bit for bit (float bits compared as integers)."""
    if isinstance(a, torch.Tensor):
        a = a.numpy()
    if isinstance(b, torch.Tensor):
        b = b.numpy()
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype != b.dtype or a.shape != b.shape:
            return False
        return a.tobytes() == b.tobytes()
    return a == b


def reference_pairs(ds):
    """The in-order reader's pairs by unit index."""
    return {p["unit_index"]: p for p in ds.pairs()}


def check_pair(p, ref, what):
    r = ref[p["unit_index"]]
    for k, v in p.items():
        assert k in r, f"{what}: field {k} not in the in-order reader's pair"
        assert same(v, r[k]), f"{what}: unit {p['unit_index']} field {k} differs from the in-order reader"


def split_batch(b):
    """The pairs of a collated batch (tensors), back as per-pair dicts (for the bit-for-bit check)."""
    out = []
    n = len(b["unit_index"])
    offs = {c: np.concatenate([[0], np.cumsum(b[f"{c}_lengths"].numpy())]) for c in ("source", "target") if f"{c}_lengths" in b}
    for j in range(n):
        p = {"unit_index": int(b["unit_index"][j])}
        for f in prd.PAIR_FIELDS:
            if f not in b or f == "unit_index":
                continue
            v = b[f]
            if f in ("source_points", "target_points", "target_known_share", "target_scene_share", "target_view"):
                o = offs["source" if f == "source_points" else "target"]
                p[f] = None if v is None else v[o[j]:o[j + 1]].numpy()
            elif f == "T_target_from_source":
                p[f] = v[j].numpy()
            elif f in ("overlap_source", "overlap_target"):
                p[f] = float(v[j])
            else:
                p[f] = v[j]
        out.append(p)
    return out


def epochs_of(make_loader, ranks, epochs=2):
    """{epoch: [unit indices in the order received, over every rank]} and every pair received."""
    seen, pairs = {}, []
    for epoch in range(epochs):
        order = []
        for rank in range(ranks):
            for b in make_loader(rank, epoch):
                for p in split_batch(b):
                    order.append(p["unit_index"])
                    pairs.append(p)
        seen[epoch] = order
    return seen, pairs


def check_once(seen, ok_units, what):
    for epoch, order in seen.items():
        assert len(order) == len(set(order)), f"{what}: epoch {epoch} gave {len(order) - len(set(order))} pairs twice"
        assert sorted(order) == ok_units, f"{what}: epoch {epoch} gave {len(order)} pairs, {len(ok_units)} expected; missing {sorted(set(ok_units) - set(order))[:5]}"
    assert seen[0] != seen[1], f"{what}: both epochs in the same order"


def group_loader(ds, ranks, workers, mix, fields=None):
    def make(rank, epoch):
        data = prd.PairDataset(ds, tensors=True, fields=fields, cache_groups=2 * mix + 2)
        sampler = prd.GroupShuffleSampler(data, batch_size=4, num_workers=workers, mix=mix, seed=3, rank=rank, world_size=ranks)
        sampler.set_epoch(epoch)
        return torch.utils.data.DataLoader(data, batch_size=4, sampler=sampler, collate_fn=prd.collate, num_workers=workers)
    return make


def stream_loader(ds, ranks, workers, buffer, piece_rows=7):
    def make(rank, epoch):
        data = prd.StreamingPairDataset(ds, tensors=True, seed=5, rank=rank, world_size=ranks, buffer_size=buffer, readahead=3, piece_rows=piece_rows)
        data.set_epoch(epoch)
        return torch.utils.data.DataLoader(data, batch_size=4, collate_fn=prd.collate, num_workers=workers)
    return make


def readers(ds, plan, ok_units, ref):
    """Checks 1 and 2 on `ds`; returns what was counted."""
    ranks, workers, buffer = plan["ranks"], plan["workers"], plan["buffer"]
    report = {}
    for mix in (1, 2):
        seen, pairs = epochs_of(group_loader(ds, ranks, workers, mix), ranks)
        check_once(seen, ok_units, f"GroupShuffleSampler(mix={mix}), {ranks} ranks x {workers} workers")
        for p in pairs:
            check_pair(p, ref, f"GroupShuffleSampler(mix={mix})")
        report[f"group_mix{mix}_pairs"] = len(pairs)
    seen, pairs = epochs_of(stream_loader(ds, ranks, workers, buffer), ranks)
    check_once(seen, ok_units, f"StreamingPairDataset, {ranks} ranks x {workers} workers")
    for p in pairs:
        check_pair(p, ref, "StreamingPairDataset")
    report["stream_pairs"] = len(pairs)
    # Projected fields: only the clouds and the pose (and the unit index), equal to the in-order reader's.
    m = prd.PairDataset(ds, fields=prd.MINIMAL_FIELDS)
    assert len(m) == len(ok_units)
    order = list(range(len(m)))
    random.Random(1).shuffle(order)
    for i in order:
        p = m[i]
        assert set(p) == {"unit_index", *prd.MINIMAL_FIELDS}, sorted(p)
        check_pair(p, ref, "PairDataset(fields=MINIMAL_FIELDS), random order")
    # Every field in a random order, the default path of a map-style trainer.
    m = prd.PairDataset(ds)
    for i in order:
        check_pair(m[i], ref, "PairDataset, random order")
    report["map_pairs"] = 2 * len(order)
    return report


def corrupt_pngs(src, dst):
    """A copy of the dataset whose depth-PNG column chunks are overwritten with 0xA5 (past the first 16
    bytes of each chunk, so the page header or the compressed data is garbage): how many were hit."""
    shutil.copytree(src, dst)
    hit = 0
    for name in sorted(os.listdir(os.path.join(dst, "shards"))):
        path = os.path.join(dst, "shards", name)
        meta = pq.ParquetFile(path).metadata
        with open(path, "r+b") as f:
            for g in range(meta.num_row_groups):
                rg = meta.row_group(g)
                for c in range(rg.num_columns):
                    col = rg.column(c)
                    if col.path_in_schema not in PNG_COLUMNS or col.total_compressed_size <= 32:
                        continue
                    start = col.dictionary_page_offset or col.data_page_offset
                    f.seek(start + 16)
                    f.write(b"\xa5" * (col.total_compressed_size - 16))
                    hit += 1
    return hit


def projection(plan, ok_units, ref):
    """Check 3."""
    bad = os.path.join(plan["scratch"], "corrupt")
    hit = corrupt_pngs(plan["dataset"], bad)
    assert hit > 0, "no PNG column chunk to corrupt: the dataset must store depth maps"
    ds = prd.open_dataset(bad)
    raised = 0
    for shard in ds.shards:
        try:
            ds.read_group(shard, 0, ["target_depth_png"])
        except Exception:  # noqa: BLE001 - any decoding error: what matters is that it fails
            raised += 1
    assert raised == len(ds.shards), f"reading the corrupted PNG column raised in {raised} of {len(ds.shards)} shards: the plant does not bite"
    report = readers(ds, dict(plan, ranks=1, workers=2), ok_units, ref)
    return {"corrupted_chunks": hit, "png_reads_raising": raised, **report}


def buffer_bound(plan, ds):
    """Check 4."""
    rng = random.Random(7)
    moved = 0
    for size in (1, 3, 16, 100):
        for n in (0, 1, size, 5 * size + 3, 1000):
            out = list(bounded_shuffle(iter(range(n)), size, rng))
            assert sorted(out) == list(range(n)), f"bounded_shuffle({n}, {size}) is not a permutation"
            worst = max((abs(o - a) for o, a in enumerate(out)), default=0)
            assert worst <= size, f"bounded_shuffle(B={size}): an item moved {worst} places"
            moved += sum(1 for o, a in enumerate(out) if o != a)
    assert moved > 0, "bounded_shuffle never moved an item"
    # Inside the streaming reader: arrival = its pieces' pairs in reading order.
    B = plan["buffer"]
    stream = prd.StreamingPairDataset(ds, seed=9, buffer_size=B, readahead=0, fields=["unit_index"])
    arrival = [p["unit_index"] for p in stream._items(stream.pieces_of(0, 1))]
    out = [p["unit_index"] for p in stream]
    at = {u: a for a, u in enumerate(arrival)}
    assert sorted(out) == sorted(arrival)
    worst = max(abs(o - at[u]) for o, u in enumerate(out))
    assert worst <= B, f"StreamingPairDataset(buffer_size={B}): a pair left {worst} places from where it arrived"
    assert out != arrival, "the streaming buffer did not shuffle"
    return {"largest_displacement": worst, "buffer": B}


def upload(src, endpoint):
    """The committed files of the folder dataset `src` into s3://loaders/ds on the local S3 server."""
    import boto3

    s3 = boto3.client("s3", endpoint_url=endpoint, aws_access_key_id="testing", aws_secret_access_key="testing", region_name="us-east-1")
    s3.create_bucket(Bucket="loaders")
    for sub in ("", "manifest", "shards"):
        for name in sorted(os.listdir(os.path.join(src, sub))):
            path = os.path.join(src, sub, name)
            if os.path.isfile(path) and (sub or name == "dataset.toml"):
                s3.upload_file(path, "loaders", "/".join(x for x in ("ds", sub, name) if x))
    return "s3://loaders/ds", {"endpoint_url": endpoint, "access_key": "testing", "secret_key": "testing", "region": "us-east-1"}


def object_store(plan, ok_units, ref):
    """Checks 1 and 2 on a local S3 server: whole-shard streaming (the default there), streaming and
    random access through local copies (cache_dir=), the copies complete and named by their blake3."""
    url, opts = upload(plan["dataset"], plan["s3_endpoint"])
    ranks, workers = plan["ranks"], plan["workers"]
    report = {}
    ds = prd.open_dataset(url, storage_options=opts)
    assert ds.remote and len(ds.shards) == len(prd.open_dataset(plan["dataset"]).shards)
    stream = prd.StreamingPairDataset(ds)
    assert len(stream.pieces) == len(ds.shards), "whole shards on an object store without cache_dir"
    seen, pairs = epochs_of(stream_loader(ds, ranks, workers, plan["buffer"], piece_rows=None), ranks)
    check_once(seen, ok_units, "StreamingPairDataset on S3 (whole shards)")
    for p in pairs:
        check_pair(p, ref, "StreamingPairDataset on S3 (whole shards)")
    report["stream_whole_shards_pairs"] = len(pairs)
    cache = os.path.join(plan["scratch"], "s3-cache")
    ds = prd.open_dataset(url, storage_options=opts, cache_dir=cache)
    seen, pairs = epochs_of(stream_loader(ds, ranks, workers, plan["buffer"]), ranks)
    check_once(seen, ok_units, "StreamingPairDataset on S3 with cache_dir")
    for p in pairs:
        check_pair(p, ref, "StreamingPairDataset on S3 with cache_dir")
    copies = sorted(os.listdir(cache))
    assert copies == sorted(s.blake3 + ".parquet" for s in ds.shards), f"the local copies are the shards, by blake3: {copies}"
    for s in ds.shards:
        assert os.path.getsize(os.path.join(cache, s.blake3 + ".parquet")) == s.entry["bytes"]
    seen, pairs = epochs_of(group_loader(ds, ranks, workers, 1), ranks)
    check_once(seen, ok_units, "GroupShuffleSampler on S3 with cache_dir")
    for p in pairs:
        check_pair(p, ref, "GroupShuffleSampler on S3 with cache_dir")
    report["stream_cached_pairs"] = report["group_cached_pairs"] = len(pairs)
    m = prd.PairDataset(prd.open_dataset(url, storage_options=opts))
    for i in random.Random(2).sample(range(len(m)), min(20, len(m))):
        check_pair(m[i], ref, "PairDataset on S3, ranged reads")
    return report


def main():
    plan = json.load(open(sys.argv[1]))
    ref_rows = pq.read_table(plan["reference"]).to_pylist()
    ok_units = sorted(r["unit_index"] for r in ref_rows if r["status"] == "ok")
    assert 0 < len(ok_units) < len(ref_rows), "the dataset must have ok and rejected rows"
    ds = prd.open_dataset(plan["dataset"])
    assert ds.schema_version == "pairs/3", ds.schema_version
    groups = [len(ds.group_rows(s)) for s in ds.shards]
    assert min(groups) > 1, f"every shard should hold several row groups: {groups}"
    ref = reference_pairs(ds)
    assert sorted(ref) == ok_units, "the in-order reader gives the ok rows of `pointreggpt query`"
    report = {"ok": len(ok_units), "rows": len(ref_rows), "row_groups": sum(groups)}
    report["readers"] = readers(ds, plan, ok_units, ref)
    report["projection"] = projection(plan, ok_units, ref)
    report["buffer"] = buffer_bound(plan, ds)
    if plan.get("s3_endpoint"):
        report["s3"] = object_store(plan, ok_units, ref)
    print(json.dumps(report))


if __name__ == "__main__":
    main()
