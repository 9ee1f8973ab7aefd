#!/usr/bin/env python3
"""A PyTorch-style dataset over the committed `pairs` shards of a pointreggpt dataset, read with pyarrow.

    from pair_dataset import PairDataset
    ds = PairDataset("out/demo")                 # the `ok` pairs, in unit order
    source, target, T = ds[0]                    # float32 (N, 3), float32 (M, 3), float64 (4, 4)
    # target ≈ source @ T[:3, :3].T + T[:3, 3] where the clouds overlap (each cloud in its own camera frame)

No torch import is needed: `__len__`/`__getitem__` are all `torch.utils.data.DataLoader` asks for (wrap the
arrays with `torch.from_numpy` in a collate function). Only the shard files named by `<dataset>/manifest/`
are read: a file in `shards/` without a manifest entry is not part of the dataset. One decoded shard is
cached, so iterate in order (or shuffle within shards) for speed.

Usage as a test (run by tests/export.rs): pair_dataset.py <dataset> <expected.json>, where the JSON lists
the `ok` rows as the Rust library reads them; prints one JSON line and exits non-zero on a mismatch.
"""
import json
import os
import sys

try:
    import numpy as np
    import pyarrow.parquet as pq
except ImportError as e:  # a missing module is a failure, not a skip
    sys.exit(f"pair_dataset.py needs numpy and pyarrow ({e}); install them with scripts/install-test-deps.sh")


def committed_shards(root, table="pairs"):
    """The shard files of `table` named by the manifest entries, sorted by shard index."""
    manifest = os.path.join(root, "manifest")
    entries = []
    for name in sorted(os.listdir(manifest)):
        if name.startswith(table + "-") and name.endswith(".json"):
            with open(os.path.join(manifest, name)) as f:
                entries.append(json.load(f))
    entries.sort(key=lambda e: e["shard"])
    return [os.path.join(root, "shards", e["file"]) for e in entries]


def points(column, row):
    """Row `row` of a `list<fixed_size_list<float32, 3>>` column as a float32 (N, 3) array."""
    values = column[row].values
    if values is None or len(values) == 0:
        return np.zeros((0, 3), np.float32)
    return np.asarray(values.flatten().to_numpy(zero_copy_only=False), dtype=np.float32).reshape(-1, 3)


class PairDataset:
    """The pairs of a dataset with the given `status` (None = every row), in `unit_index` order."""

    COLUMNS = ["pair_key", "source_points", "target_points", "t_target_from_source"]

    def __init__(self, root, status="ok"):
        self.files = committed_shards(root)
        index = []
        for fi, path in enumerate(self.files):
            t = pq.read_table(path, columns=["unit_index", "status"])
            for row, (unit, st) in enumerate(zip(t.column("unit_index").to_pylist(), t.column("status").to_pylist())):
                if status is None or st == status:
                    index.append((unit, fi, row))
        index.sort()
        self.unit_index = [u for u, _, _ in index]
        self._where = [(fi, row) for _, fi, row in index]
        self._cached = (None, None)

    def __len__(self):
        return len(self._where)

    def _table(self, fi):
        if self._cached[0] != fi:
            self._cached = (fi, pq.read_table(self.files[fi], columns=self.COLUMNS))
        return self._cached[1]

    def _locate(self, i):
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        return self._where[i]

    def pair_key(self, i):
        fi, row = self._locate(i)
        return self._table(fi).column("pair_key")[row].as_py()

    def __getitem__(self, i):
        """(source_points float32 (N, 3), target_points float32 (M, 3), T_target_from_source float64 (4, 4))."""
        fi, row = self._locate(i)
        t = self._table(fi)
        transform = np.asarray(t.column("t_target_from_source")[row].as_py(), dtype=np.float64).reshape(4, 4)
        return points(t.column("source_points"), row), points(t.column("target_points"), row), transform


def check(root, expected):
    """Compares PairDataset(root) with `expected` (a list of the ok rows: pair_key, unit_index, point
    counts, the 16 transform values, first/last points and coordinate sums). Raises AssertionError."""
    ds = PairDataset(root)
    assert len(ds) == len(expected), f"{len(ds)} pairs, expected {len(expected)}"
    assert ds.unit_index == [e["unit_index"] for e in expected]
    for i, e in enumerate(expected):
        src, tgt, T = ds[i]
        assert ds.pair_key(i) == e["pair_key"], (ds.pair_key(i), e["pair_key"])
        assert src.dtype == np.float32 and tgt.dtype == np.float32 and T.dtype == np.float64
        assert src.shape == (e["n_source"], 3) and tgt.shape == (e["n_target"], 3), (src.shape, tgt.shape)
        assert T.shape == (4, 4) and T.ravel().tolist() == e["t"], "transform differs"
        for cloud, first, last, total in [(src, "source_first", "source_last", "source_sum"), (tgt, "target_first", "target_last", "target_sum")]:
            assert cloud[0].tolist() == e[first] and cloud[-1].tolist() == e[last], f"{e['pair_key']}: {first}/{last}"
            assert np.allclose(cloud.astype(np.float64).sum(axis=0), e[total], rtol=1e-9, atol=1e-9), f"{e['pair_key']}: {total}"
    # Negative indexing and the end.
    assert ds[-1][2].ravel().tolist() == expected[-1]["t"]
    try:
        ds[len(ds)]
        raise AssertionError("index past the end did not raise IndexError")
    except IndexError:
        pass
    return len(ds)


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: pair_dataset.py <dataset> <expected.json>")
    with open(sys.argv[2]) as f:
        expected = json.load(f)
    n = check(sys.argv[1], expected)
    print(json.dumps({"pairs": n, "files": len(committed_shards(sys.argv[1]))}))


if __name__ == "__main__":
    main()
