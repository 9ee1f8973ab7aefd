#!/usr/bin/env python3
"""Checks the installed `pointreggpt_data` package (python/ in the repository, installed by
scripts/install-test-deps.sh) against `pointreggpt query` on the same dataset. Run by tests/python_package.rs.

Usage: check_package.py <plan.json>

plan.json:
  dataset          folder or s3:// URL
  storage_options  explicit options for open_dataset (null for a folder)
  env              (S3) environment variables with which the dataset is opened a second time without options
  reference        a Parquet file written by `pointreggpt query ... --format parquet`: every row, unit order,
                   columns unit_index, pair_key, scene, status, seed, t_target_from_source, source_points,
                   target_points, overlap_source, overlap_target (+ target_known_share, target_view from version 2,
                   target_scene_share in version 3)
  schema_version   "pairs/3", "pairs/2" or "pairs/1"
  shards           the number of committed shards (manifest entries)
  filters          [{"kwargs": {...selection arguments...}, "where": python expression over `pc` or null,
                     "keys": [pair keys `pointreggpt query` selects with the same predicate, in unit order]}]
  source           the package's source folder (python/pointreggpt_data): the installed copy must equal it
  plant_uncommitted  copy a committed shard under another name in shards/ first (it must not be read)
  count_bytes      (folder) check that selecting rows reads only the small columns
  loader_workers   DataLoader workers for the torch check
  streaming        {"ranks": R, "workers": W}: StreamingPairDataset over R simulated ranks x W DataLoader
                   workers, two epochs, every ok pair exactly once per epoch; PairDataset in a random order
  any_rows_per_filter  do not require a filter that selects some rows but not all (a fixture of unknown content)

Every comparison is exact: points bit for bit (float32 bits), transforms and overlaps as stored, the
seed as the unit's unsigned seed. Prints one JSON object; exits non-zero (AssertionError) on a mismatch.
"""
import filecmp
import json
import random
import os
import sys

try:
    import numpy as np
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.fs as pafs
    import pyarrow.parquet as pq
except ImportError as e:  # a missing module is a failure, not a skip
    sys.exit(f"check_package.py needs numpy and pyarrow ({e}): scripts/install-test-deps.sh")

try:
    import pointreggpt_data as prd
except ImportError as e:
    sys.exit(f"the pointreggpt_data package is not installed ({e}): run scripts/install-test-deps.sh (pip install ./python)")

U64 = (1 << 64) - 1


def check_installed(source):
    """The installed package is the repository's python/pointreggpt_data, file for file."""
    installed = os.path.dirname(os.path.abspath(prd.__file__))
    assert os.path.abspath(installed) != os.path.abspath(source), f"imported from the source tree {source}, not installed"
    names = sorted(n for n in os.listdir(source) if n.endswith(".py"))
    assert names, f"no Python files in {source}"
    stale = [n for n in names if not os.path.exists(os.path.join(installed, n)) or not filecmp.cmp(os.path.join(source, n), os.path.join(installed, n), shallow=False)]
    assert not stale, f"the installed pointreggpt_data ({installed}) differs from {source} in {stale}: run scripts/install-test-deps.sh"
    return installed


def as_f32(values):
    """A list of float32 values decoded by pyarrow's to_pylist (Python floats) back to float32: exact."""
    return np.array(values, dtype=np.float32)


def reference_rows(path, version):
    """The rows of `pointreggpt query`, decoded without the package (to_pylist)."""
    t = pq.read_table(path)
    want_types = {"pairs/3": (pa.int64(), pa.int64()), "pairs/2": (pa.int64(), pa.int64()), "pairs/1": (pa.uint64(), pa.uint64())}[version]
    assert (t.schema.field("unit_index").type, t.schema.field("seed").type) == want_types, t.schema
    assert ("target_known_share" in t.column_names) == (version != "pairs/1"), t.column_names
    assert ("target_scene_share" in t.column_names) == (version == "pairs/3"), t.column_names
    rows = []
    for r in t.to_pylist():
        r["source_points"] = as_f32(r["source_points"]).reshape(-1, 3)
        r["target_points"] = as_f32(r["target_points"]).reshape(-1, 3)
        r["T"] = np.array(r["t_target_from_source"], dtype=np.float64).reshape(4, 4)
        if version != "pairs/1":
            r["target_known_share"] = as_f32(r["target_known_share"])
            r["target_view"] = np.array(r["target_view"], dtype=np.int8)
            # Version 2 had no scene: its scene shares read as 0, one per point.
            r["target_scene_share"] = as_f32(r["target_scene_share"]) if version == "pairs/3" else np.zeros(len(r["target_known_share"]), np.float32)
        rows.append(r)
    return rows


def same_bits(a, b):
    """Equal shape, dtype and bits (so -0.0 and NaN payloads count)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def check_pair(p, r, version, where):
    key = r["pair_key"]
    assert p["pair_key"] == key, f"{where}: {p['pair_key']} vs {key}"
    assert (p["scene"], p["status"], p["unit_index"]) == (r["scene"], r["status"], r["unit_index"]), f"{where} {key}"
    assert type(p["seed"]) is int and 0 <= p["seed"] <= U64, f"{where} {key}: seed {p['seed']!r}"
    assert p["seed"] == r["seed"] & U64, f"{where} {key}: seed {p['seed']} vs stored {r['seed']}"
    if version != "pairs/1" and r["seed"] < 0:
        assert p["seed"] >= 1 << 63, "a negative stored seed is an unsigned seed >= 2**63"
    src, tgt, T = (np.asarray(p[k]) for k in ("source_points", "target_points", "T_target_from_source"))
    assert same_bits(src, r["source_points"]), f"{where} {key}: source points"
    assert same_bits(tgt, r["target_points"]), f"{where} {key}: target points"
    assert same_bits(T, r["T"]), f"{where} {key}: transform"
    assert p["overlap_source"] == r["overlap_source"] and p["overlap_target"] == r["overlap_target"], f"{where} {key}: overlaps"
    if version != "pairs/1":
        assert same_bits(np.asarray(p["target_known_share"]), r["target_known_share"]), f"{where} {key}: target_known_share"
        assert same_bits(np.asarray(p["target_scene_share"]), r["target_scene_share"]), f"{where} {key}: target_scene_share"
        assert same_bits(np.asarray(p["target_view"]), r["target_view"]), f"{where} {key}: target_view"
        assert len(r["target_view"]) == len(r["target_points"])
    else:
        assert p["target_known_share"] is None and p["target_scene_share"] is None and p["target_view"] is None, f"{where} {key}: a version-1 pair has no provenance"


def selection(f):
    kw = dict(f["kwargs"])
    for k in ("overlap_source", "overlap_target"):
        if k in kw and kw[k] is not None:
            kw[k] = tuple(kw[k])
    if f.get("where"):
        kw["where"] = eval(f["where"], {"pc": pc})  # test-only: an expression such as pc.field("sample_index") == 0
    return kw


class CountingFile:
    """A file object that counts the bytes read through it."""

    def __init__(self, f, counter):
        self.f, self.counter = f, counter
        self.closed = False

    def read(self, n=-1):
        data = self.f.read(n)
        self.counter[0] += len(data)
        return data

    def seek(self, *a):
        return self.f.seek(*a)

    def tell(self):
        return self.f.tell()

    def close(self):
        self.closed = True
        self.f.close()

    def readable(self):
        return True

    def seekable(self):
        return True


class CountingHandler(pafs.FileSystemHandler):
    """The local filesystem, read-only, counting the bytes read from files."""

    def __init__(self):
        self.local, self.counter = pafs.LocalFileSystem(), [0]

    def get_type_name(self):
        return "counting"

    def normalize_path(self, path):
        return path

    def equals(self, other):
        return self is other

    def get_file_info(self, paths):
        return self.local.get_file_info(paths)

    def get_file_info_selector(self, selector):
        return self.local.get_file_info(selector)

    def open_input_stream(self, path):
        return pa.PythonFile(CountingFile(open(path, "rb"), self.counter), mode="r")

    def open_input_file(self, path):
        return pa.PythonFile(CountingFile(open(path, "rb"), self.counter), mode="r")

    def _refuse(self, *a, **k):
        raise OSError("read-only")

    create_dir = delete_dir = delete_dir_contents = delete_root_dir_contents = delete_file = move = copy_file = _refuse
    open_output_stream = open_append_stream = _refuse


def chunk_bytes(files, names):
    """Compressed bytes of the column chunks of `names` (top-level columns) in `files`."""
    total = 0
    for f in files:
        m = pq.ParquetFile(f).metadata
        for g in range(m.num_row_groups):
            rg = m.row_group(g)
            total += sum(rg.column(i).total_compressed_size for i in range(rg.num_columns) if rg.column(i).path_in_schema.split(".")[0] in names)
    return total


def check_bytes_read(path):
    """Selecting rows reads the footers and the small columns it needs, nothing else: less than the
    source clouds alone; reading pairs reads the clouds but not the depth PNGs."""
    handler = CountingHandler()
    ds = prd.open_dataset(path, filesystem=pafs.PyFileSystem(handler))
    files, total = ds.files, sum(os.path.getsize(f) for f in ds.files)
    footers = sum(min(65536, os.path.getsize(f)) for f in files)  # pyarrow reads up to 64 KiB to find a footer
    handler.counter[0] = 0  # (dataset.toml and the manifest entries)
    for shard in ds.shards:
        ds.fragment(shard)
    assert handler.counter[0] <= footers, (handler.counter[0], footers)
    handler.counter[0] = 0
    keys = ds.pair_keys(status=None, overlap_source=(0.0, 1.0))
    index_bytes = handler.counter[0]
    handler.counter[0] = 0
    n = sum(1 for _ in ds.pairs(status=None))
    pair_bytes = handler.counter[0]
    handler.counter[0] = 0
    pngs = ["source_depth_png", "condition_depth_png", "target_depth_png", "known_mask_png"]
    ds.to_table(columns=["pair_key"] + pngs, status=None)
    png_bytes = handler.counter[0]
    assert len(keys) == n == ds.num_rows
    small = chunk_bytes(files, ["unit_index", "pair_key", "overlap_source"])
    assert index_bytes == small, f"selecting rows read {index_bytes} bytes, its three columns are {small}"
    want_pairs = chunk_bytes(files, ["unit_index", "pair_key", "scene", "status", "seed", "t_target_from_source", "source_points",
                                     "target_points", "target_known_share", "target_scene_share", "target_view", "overlap_source", "overlap_target"])
    # Reads of neighbouring chunks are merged across holes below 8 KiB (pyarrow's pre-buffering), so a
    # few small columns between them may be read too, never a PNG column (the smallest is larger).
    assert want_pairs <= pair_bytes < want_pairs + chunk_bytes(files, ["known_mask_png"]), f"pairs() read {pair_bytes} bytes, its columns are {want_pairs}"
    assert png_bytes == chunk_bytes(files, ["pair_key"] + pngs) > 0.1 * total
    assert index_bytes < chunk_bytes(files, ["source_points"])
    return {"shard_bytes": total, "index_bytes": index_bytes, "pair_bytes": pair_bytes, "png_bytes": png_bytes}


def check_loader(ds, kwargs, by_key, version, workers):
    """DataLoader + collate with torch tensors and the shard-by-shard sampler: every selected pair exactly
    once, each batch's concatenation split back by its lengths equal to the reference rows."""
    import torch

    train = prd.PairDataset(ds, tensors=True, **kwargs)
    assert isinstance(train, torch.utils.data.Dataset)
    sampler = prd.ShardShuffleSampler(train, seed=3)
    order = list(sampler)
    assert sorted(order) == list(range(len(train))), "the sampler is a permutation"
    shards_in_order = [train.shard_of(i) for i in order]
    runs = [s for j, s in enumerate(shards_in_order) if j == 0 or shards_in_order[j - 1] != s]
    assert len(runs) == len(set(runs)), f"each shard's items are contiguous: {shards_in_order}"
    sampler.set_epoch(1)
    assert sorted(sampler) == list(range(len(train)))
    sampler.set_epoch(0)
    context = os.environ.get("CHECK_PACKAGE_LOADER_CONTEXT") if workers else None  # "spawn" for az:// (manual runs)
    loader = torch.utils.data.DataLoader(train, batch_size=3, sampler=sampler, collate_fn=prd.collate, num_workers=workers, multiprocessing_context=context)
    seen, batches = [], 0
    for b in loader:
        batches += 1
        B = len(b["pair_key"])
        assert b["source_points"].dtype == torch.float32 and b["target_points"].dtype == torch.float32
        assert b["T_target_from_source"].shape == (B, 4, 4) and b["T_target_from_source"].dtype == torch.float64
        for cloud in ("source", "target"):
            lengths, index = b[f"{cloud}_lengths"], b[f"{cloud}_batch"]
            assert lengths.dtype == torch.int64 and lengths.shape == (B,) and int(lengths.sum()) == b[f"{cloud}_points"].shape[0]
            assert torch.equal(index, torch.repeat_interleave(torch.arange(B), lengths))
        src = torch.split(b["source_points"], b["source_lengths"].tolist())
        tgt = torch.split(b["target_points"], b["target_lengths"].tolist())
        for j, key in enumerate(b["pair_key"]):
            r = by_key[key]
            assert same_bits(src[j].numpy(), r["source_points"]) and same_bits(tgt[j].numpy(), r["target_points"]), f"loader {key}: points"
            assert same_bits(b["T_target_from_source"][j].numpy(), r["T"]), f"loader {key}: transform"
            assert b["overlap_source"][j].item() == r["overlap_source"] and b["seed"][j] == r["seed"] & U64
            assert b["unit_index"][j].item() == r["unit_index"]
        if version != "pairs/1":
            assert b["target_known_share"].shape[0] == b["target_points"].shape[0] == b["target_view"].shape[0] == b["target_scene_share"].shape[0]
            assert b["target_view"].dtype == torch.int8
            known = torch.split(b["target_known_share"], b["target_lengths"].tolist())
            view = torch.split(b["target_view"], b["target_lengths"].tolist())
            for j, key in enumerate(b["pair_key"]):
                assert same_bits(known[j].numpy(), by_key[key]["target_known_share"]) and same_bits(view[j].numpy(), by_key[key]["target_view"])
        else:
            assert b["target_known_share"] is None and b["target_view"] is None
        seen += b["pair_key"]
    assert seen == [train[i]["pair_key"] for i in order], "batches follow the sampler's order"
    # numpy samples collate to numpy arrays
    plain = prd.PairDataset(ds, **kwargs)
    if len(plain) >= 2:
        nb = prd.collate([plain[0], plain[1]])
        assert isinstance(nb["source_points"], np.ndarray) and nb["source_lengths"].tolist() == [len(plain[0]["source_points"]), len(plain[1]["source_points"])]
    return {"batches": batches, "pairs": len(seen), "workers": workers}


def check_streaming(ds, by_key, version, plan):
    """StreamingPairDataset across ``ranks`` simulated ranks × ``workers`` DataLoader worker processes: each
    epoch, the pairs of all consumers together are the `ok` pairs exactly once (against the query's list),
    each bit for bit as the reference; another epoch, another order; the row groups of a shard are read
    each on its own (a shard of several row groups is split between consumers). And the map-style
    PairDataset, read in a random order, gives every pair as the reference."""
    import torch

    ranks, workers = plan["ranks"], plan["workers"]
    ok_keys = sorted(k for k, r in by_key.items() if r["status"] == "ok")
    pieces = prd.StreamingPairDataset(ds, seed=5).pieces
    assert len(pieces) > len(ds.shards), f"some shard has several row groups: {len(pieces)} row groups in {len(ds.shards)} shards"
    assert len(ds.shards) % workers and len(pieces) % (ranks * workers), "shards and row groups that do not divide evenly"
    orders = []
    for epoch in range(2):
        seen, per_consumer = [], []
        for rank in range(ranks):
            stream = prd.StreamingPairDataset(ds, tensors=True, seed=5, buffer_size=8, rank=rank, world_size=ranks)
            assert isinstance(stream, torch.utils.data.IterableDataset)
            stream.set_epoch(epoch)
            loader = torch.utils.data.DataLoader(stream, batch_size=3, collate_fn=prd.collate, num_workers=workers)
            keys = []
            for b in loader:
                src = torch.split(b["source_points"], b["source_lengths"].tolist())
                tgt = torch.split(b["target_points"], b["target_lengths"].tolist())
                for j, key in enumerate(b["pair_key"]):
                    r = by_key[key]
                    assert same_bits(src[j].numpy(), r["source_points"]) and same_bits(tgt[j].numpy(), r["target_points"]), f"stream {key}: points"
                    assert same_bits(b["T_target_from_source"][j].numpy(), r["T"]), f"stream {key}: transform"
                keys += b["pair_key"]
            per_consumer.append(len(keys))
            seen += keys
        assert len(seen) == len(set(seen)), f"epoch {epoch}: {len(seen) - len(set(seen))} pairs seen twice"
        assert sorted(seen) == ok_keys, f"epoch {epoch}: {len(seen)} pairs streamed, {len(ok_keys)} ok pairs committed"
        orders.append(seen)
    assert orders[0] != orders[1], "another epoch, another order"
    # Unshuffled, one consumer: every pair in unit order within each row group, row groups in file order.
    plain = prd.StreamingPairDataset(ds, shuffle=False)
    assert sorted(p["pair_key"] for p in plain) == ok_keys
    # Map-style random access, one row group read per item.
    mapped = prd.PairDataset(ds)
    order = list(range(len(mapped)))
    random.Random(7).shuffle(order)
    for i in order:
        p = mapped[i]
        check_pair(p, by_key[p["pair_key"]], version, f"PairDataset[{i}]")
    return {"pieces": len(pieces), "shards": len(ds.shards), "epochs": len(orders), "pairs": len(orders[0])}


def check_store_parsing():
    """URL forms and option spellings, without a server (constructing a client connects nowhere)."""
    key = "a2V5"
    fs, base = prd.filesystem_for("abfss://box@acct.dfs.core.windows.net/some/prefix/", {"account_key": key, "endpoint": "http://127.0.0.1:9"})
    args = fs.__reduce__()[1][0]
    assert base == "box/some/prefix" and args["account_name"] == "acct" and args["account_key"] == key, (base, args)
    assert (args["blob_storage_authority"], args["blob_storage_scheme"]) == ("127.0.0.1:9", "http"), args
    fs, base = prd.filesystem_for("az://box", {"account_name": "other", "sas_token": "sv=1"})
    assert base == "box" and fs.__reduce__()[1][0]["sas_token"] == "sv=1"
    saved = {k: os.environ.pop(k) for k in list(os.environ) if k.startswith("AZURE_STORAGE")}
    try:
        prd.filesystem_for("az://box/p")
        raise AssertionError("an az:// URL without an account was accepted")
    except prd.StoreError as e:
        assert "account_name" in str(e)
    finally:
        os.environ.update(saved)
    fs, base = prd.filesystem_for("s3a://bucket/deep/prefix", {"aws_endpoint": "http://127.0.0.1:9", "aws_access_key_id": "k", "aws_secret_access_key": "s", "aws_region": "eu-west-1"})
    assert base == "bucket/deep/prefix" and fs.region == "eu-west-1", (base, fs.region)
    assert "127.0.0.1:9" in str(fs.__reduce__()), fs.__reduce__()
    for bad, why in [("s3:///prefix", "no bucket"), ("ftp://host/x", "unknown URL scheme")]:
        try:
            prd.filesystem_for(bad)
            raise AssertionError(f"{bad} was accepted")
        except prd.StoreError as e:
            assert why in str(e), e
    try:
        prd.filesystem_for("/tmp/x", {"access_key": "k"})
        raise AssertionError("storage_options for a folder were accepted")
    except prd.StoreError:
        pass
    try:
        prd.open_dataset(os.path.dirname(os.path.abspath(__file__)))
        raise AssertionError("a folder without dataset.toml opened")
    except prd.DatasetError as e:
        assert "no dataset.toml" in str(e)
    return True


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: check_package.py <plan.json>")
    with open(sys.argv[1]) as f:
        plan = json.load(f)
    report = {"installed": check_installed(plan["source"])}
    version = plan["schema_version"]
    ref = reference_rows(plan["reference"], version)
    by_key = {r["pair_key"]: r for r in ref}
    ds = prd.open_dataset(plan["dataset"], storage_options=plan.get("storage_options"))
    if plan.get("plant_uncommitted"):
        # A shard object without a manifest entry, as a writer that lost a race leaves one: never read.
        first = ds.files[0]
        stray = first.rsplit("/", 1)[0] + "/pairs-000099-uncommitted.parquet"
        ds.filesystem.copy_file(first, stray)
        ds = prd.open_dataset(plan["dataset"], storage_options=plan.get("storage_options"))
        report["planted"] = stray
    assert ds.schema_version == version and ds.has_provenance == (version != "pairs/1"), (ds.schema_version, ds.has_provenance)
    assert len(ds.shards) == plan["shards"], f"{len(ds.shards)} committed shards, the manifest has {plan['shards']}"
    assert ds.num_rows == len(ref), f"{ds.num_rows} rows, query gives {len(ref)}"

    # Every row, shard by shard, against the query's rows.
    pairs = list(ds.pairs(status=None))
    assert [p["pair_key"] for p in pairs] == [r["pair_key"] for r in ref], "rows and order (unit order) as query gives them"
    for p, r in zip(pairs, ref):
        check_pair(p, r, version, "pairs()")
    report["rows"] = len(pairs)
    report["negative_seeds"] = sum(1 for r in ref if r["seed"] < 0)

    # Filters against query's predicates; PairDataset too.
    filters = []
    for f in plan["filters"]:
        kw = selection(f)
        got = ds.pair_keys(**kw)
        assert got == f["keys"], f"filter {f['kwargs']} {f.get('where')}: {got} vs query {f['keys']}"
        assert [p["pair_key"] for p in ds.pairs(**kw)] == f["keys"], f"pairs() with {f['kwargs']}"
        tds = prd.PairDataset(ds, **kw)
        assert len(tds) == len(f["keys"]) and [tds[i]["pair_key"] for i in range(len(tds))] == f["keys"]
        for i in range(len(tds)):
            check_pair(tds[i], by_key[f["keys"][i]], version, f"PairDataset({f['kwargs']})")
        if len(tds):
            assert tds[-1]["pair_key"] == f["keys"][-1]
        try:
            tds[len(tds)]
            raise AssertionError("an index past the end did not raise IndexError")
        except IndexError:
            pass
        filters.append(len(got))
    report["filters"] = filters
    if not plan.get("any_rows_per_filter"):
        assert any(0 < n < len(ref) for n in filters), "some filter selects some rows but not all"

    # DataLoader + collate (torch), over the `ok` pairs.
    report["loader"] = check_loader(ds, {"status": "ok"}, by_key, version, plan.get("loader_workers", 0))
    report["ok"] = sum(1 for r in ref if r["status"] == "ok")
    assert report["loader"]["pairs"] == report["ok"]

    if plan.get("streaming"):
        report["streaming"] = check_streaming(ds, by_key, version, plan["streaming"])
    if plan.get("count_bytes"):
        report["bytes"] = check_bytes_read(plan["dataset"])
    if plan.get("env"):
        # The same dataset with the credentials and endpoint of the environment only.
        os.environ.update(plan["env"])
        env_ds = prd.open_dataset(plan["dataset"])
        assert env_ds.files == ds.files
        p = next(env_ds.pairs(status=None))
        check_pair(p, ref[0], version, "environment credentials")
        report["env"] = True
    report["store_parsing"] = check_store_parsing()
    print(json.dumps(report))


if __name__ == "__main__":
    main()
