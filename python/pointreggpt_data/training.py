"""A map-style dataset of pairs for ``torch.utils.data.DataLoader``, a shard-aware sampler, and ``collate``
for clouds of different sizes. torch is optional: without it ``PairDataset`` is a plain class with the
same ``__len__``/``__getitem__`` (numpy samples), and ``collate`` returns numpy arrays.
"""

import random

import numpy as np

from .dataset import (
    INDEX_COLUMNS, PAIR_COLUMNS, PROVENANCE_COLUMNS, DecodedShard, ShardCache, open_dataset, selection_expression,
)

try:  # optional
    import torch as _torch
    from torch.utils.data import Dataset as _Base
except ImportError:  # pragma: no cover - exercised only without torch
    _torch = None
    _Base = object

#: Per-point fields that ``collate`` concatenates, with the cloud whose lengths they follow.
_POINT_FIELDS = (("source_points", "source"), ("target_points", "target"),
                 ("target_known_share", "target"), ("target_view", "target"))


class PairDataset(_Base):
    """The selected pairs of a dataset, indexable in unit order; each item is a dict (``PAIR_FIELDS`` of
    ``pointreggpt_data.dataset``): source/target points float32 (N, 3)/(M, 3), ``T_target_from_source``
    float64 (4, 4), both overlaps, the per-point provenance (``None`` for a version-1 dataset), pair key,
    scene, status, unit index and the unsigned seed.

    ``dataset``: a ``Dataset`` or a URL/path (opened with ``storage_options``). Selection: ``status``
    (default ``"ok"``; ``None`` for every row), ``scene``, ``overlap_source``/``overlap_target`` (inclusive
    ``(low, high)``), ``where`` (a ``pyarrow.compute`` expression over ``INDEX_COLUMNS``). ``tensors=True``
    returns torch tensors instead of numpy arrays. ``columns``: more columns to return, as Python values
    (e.g. ``["source_intrinsics"]``). ``cache_shards``: decoded shards kept per process (1 by default:
    iterate in order or with ``ShardShuffleSampler``; a fully random order reads a shard per item).

    Building the index reads only ``INDEX_COLUMNS`` of each shard; an item reads the pair columns of its
    shard once (then served from the cache).
    """

    def __init__(self, dataset, status="ok", scene=None, overlap_source=None, overlap_target=None, where=None,
                 tensors=False, columns=(), cache_shards=1, storage_options=None):
        if tensors and _torch is None:
            raise ImportError("PairDataset(tensors=True) needs torch (pip install torch)")
        self.dataset = dataset if hasattr(dataset, "shards") else open_dataset(dataset, storage_options=storage_options)
        self.tensors = tensors
        self.columns = list(columns)
        self.cache_shards = cache_shards
        self._filter = selection_expression(status, scene, overlap_source, overlap_target, where)
        index = []  # (unit_index, shard position)
        for k, shard in enumerate(self.dataset.shards):
            units = self.dataset.read_shard(shard, ["unit_index"], self._filter).column("unit_index").to_pylist()
            index.extend((int(u), k) for u in units)
        index.sort()
        self.unit_index = [u for u, _ in index]
        self._shard = [k for _, k in index]
        self._cache = None

    def __len__(self):
        return len(self.unit_index)

    def shard_of(self, i):
        """The position (in ``dataset.shards``) of the shard holding item ``i``."""
        return self._shard[i]

    def _decoded(self, k):
        if self._cache is None:  # made lazily, so each DataLoader worker process has its own
            self._cache = ShardCache(self.cache_shards)
        wanted = PAIR_COLUMNS + PROVENANCE_COLUMNS + [c for c in self.columns if c not in PAIR_COLUMNS + PROVENANCE_COLUMNS]
        shard = self.dataset.shards[k]
        return self._cache.get(k, lambda: DecodedShard(self.dataset.read_shard(shard, wanted, self._filter), extra=self.columns))

    def __getitem__(self, i):
        i = int(i)
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        k, unit = self._shard[i], self.unit_index[i]
        row = self._decoded(k).row_of.get(unit)
        if row is None:
            raise RuntimeError(f"shard {self.dataset.shards[k].path} has no unit {unit} any more: it changed since the index was built")
        item = self._decoded(k).pair(row)
        if self.tensors:
            for key, value in item.items():
                if isinstance(value, np.ndarray):
                    item[key] = _torch.from_numpy(value)
        return item

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_cache"] = None  # decoded shards stay in the process that decoded them
        return state


class ShardShuffleSampler:
    """Indices of a ``PairDataset`` in a shuffled order that reads each shard once per epoch: the shards in
    a random order, the items of each shard shuffled. ``set_epoch(e)`` changes the order (the seed is
    ``seed + epoch``). Pass it as ``DataLoader(..., sampler=ShardShuffleSampler(ds))``."""

    def __init__(self, dataset, seed=0):
        self.dataset = dataset
        self.seed = seed
        self.epoch = 0

    def set_epoch(self, epoch):
        self.epoch = int(epoch)

    def __len__(self):
        return len(self.dataset)

    def __iter__(self):
        rng = random.Random(self.seed + self.epoch)
        by_shard = {}
        for i in range(len(self.dataset)):
            by_shard.setdefault(self.dataset.shard_of(i), []).append(i)
        shards = sorted(by_shard)
        rng.shuffle(shards)
        for k in shards:
            items = by_shard[k]
            rng.shuffle(items)
            yield from items


def collate(samples):
    """Batches pairs of different sizes the way KPConv-style trainers do (GeoTransformer's "stack mode"):
    the clouds of the batch are concatenated, with their lengths and a batch index per point.

    Returns a dict (torch tensors when the samples hold tensors, ``PairDataset(tensors=True)``; numpy
    arrays otherwise), for a batch of B pairs with N_b source and M_b target points:

    - ``source_points`` (sum N_b, 3) float32, ``target_points`` (sum M_b, 3) float32: pair 0's points
      first, then pair 1's, ...;
    - ``source_lengths``, ``target_lengths`` (B,) int64: N_b and M_b (pair b's points are rows
      ``lengths[:b].sum()`` to ``lengths[:b + 1].sum()``);
    - ``source_batch`` (sum N_b,), ``target_batch`` (sum M_b,) int64: the pair index of every point;
    - ``target_known_share`` (sum M_b,) float32 and ``target_view`` (sum M_b,) int8, aligned with
      ``target_points``; ``None`` when a sample has no provenance (version-1 datasets);
    - ``T_target_from_source`` (B, 4, 4) float64, ``overlap_source``/``overlap_target`` (B,) float64,
      ``unit_index`` (B,) int64;
    - ``pair_key``, ``scene``, ``status``: lists of B strings; ``seed``: a list of B Python ints (unsigned
      64-bit, which an int64 tensor cannot hold); any extra ``columns`` as lists.
    """
    if not samples:
        raise ValueError("collate: empty batch")
    as_torch = _torch is not None and isinstance(samples[0]["source_points"], _torch.Tensor)
    to_np = (lambda x: x.numpy()) if as_torch else np.asarray
    out = {}
    for cloud in ("source", "target"):
        lengths = np.array([len(s[f"{cloud}_points"]) for s in samples], dtype=np.int64)
        out[f"{cloud}_lengths"] = lengths
        out[f"{cloud}_batch"] = np.repeat(np.arange(len(samples), dtype=np.int64), lengths)
    for field, _ in _POINT_FIELDS:
        values = [s.get(field) for s in samples]
        if any(v is None for v in values):
            out[field] = None
        else:
            out[field] = np.concatenate([to_np(v) for v in values], axis=0)
    out["T_target_from_source"] = np.stack([to_np(s["T_target_from_source"]) for s in samples]).astype(np.float64, copy=False)
    for field in ("overlap_source", "overlap_target"):
        out[field] = np.array([s[field] for s in samples], dtype=np.float64)
    out["unit_index"] = np.array([s["unit_index"] for s in samples], dtype=np.int64)
    if as_torch:
        out = {k: (_torch.from_numpy(v) if isinstance(v, np.ndarray) else v) for k, v in out.items()}
    for field in samples[0]:
        if field not in out:
            out[field] = [s[field] for s in samples]
    return out


__all__ = ["PairDataset", "ShardShuffleSampler", "collate", "INDEX_COLUMNS"]
