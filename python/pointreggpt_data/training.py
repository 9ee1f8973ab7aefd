"""Datasets of pairs for ``torch.utils.data.DataLoader``: ``StreamingPairDataset`` (iterable: streams the
committed shards row group by row group, shuffled through a bounded buffer, split between workers and
ranks; the fast path for training), ``PairDataset`` (map-style: one item reads one row group), a
shard-aware sampler, and ``collate`` for clouds of different sizes. torch is optional: without it both are
plain classes (numpy samples), and ``collate`` returns numpy arrays.
"""

import random

import numpy as np

from .dataset import (
    INDEX_COLUMNS, PAIR_COLUMNS, PROVENANCE_COLUMNS, DecodedShard, ShardCache, open_dataset, selection_expression,
)

try:  # optional
    import torch as _torch
    from torch.utils.data import Dataset as _Base
    from torch.utils.data import IterableDataset as _IterBase
except ImportError:  # pragma: no cover - exercised only without torch
    _torch = None
    _Base = object
    _IterBase = object

#: Per-point fields that ``collate`` concatenates, with the cloud whose lengths they follow.
_POINT_FIELDS = (("source_points", "source"), ("target_points", "target"),
                 ("target_known_share", "target"), ("target_scene_share", "target"), ("target_view", "target"))


class PairDataset(_Base):
    """The selected pairs of a dataset, indexable in unit order; each item is a dict (``PAIR_FIELDS`` of
    ``pointreggpt_data.dataset``): source/target points float32 (N, 3)/(M, 3), ``T_target_from_source``
    float64 (4, 4), both overlaps, the per-point provenance (``None`` for a version-1 dataset), pair key,
    scene, status, unit index and the unsigned seed.

    ``dataset``: a ``Dataset`` or a URL/path (opened with ``storage_options``). Selection: ``status``
    (default ``"ok"``; ``None`` for every row), ``scene``, ``overlap_source``/``overlap_target`` (inclusive
    ``(low, high)``), ``where`` (a ``pyarrow.compute`` expression over ``INDEX_COLUMNS``). ``tensors=True``
    returns torch tensors instead of numpy arrays. ``columns``: more columns to return, as Python values
    (e.g. ``["source_intrinsics"]``). ``cache_shards``: decoded row groups kept per process (1 by
    default: iterate in order or with ``ShardShuffleSampler``; a fully random order reads a row group per
    item: at most the build's ``output.row_group_rows`` pairs, 16 by default). For training, ``StreamingPairDataset`` is faster.

    Building the index reads only the unit indices (and the filter's columns) of each row group; an item
    reads the pair columns of its row group once (then served from the cache).
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
        index = []  # (unit_index, shard position, row group)
        for k, shard in enumerate(self.dataset.shards):
            for g in range(len(self.dataset.row_groups(shard))):
                units = self.dataset.read_row_group(shard, g, ["unit_index"], self._filter).column("unit_index").to_pylist()
                index.extend((int(u), k, g) for u in units)
        index.sort()
        self.unit_index = [u for u, _, _ in index]
        self._shard = [k for _, k, _ in index]
        self._group = [g for _, _, g in index]
        self._cache = None

    def __len__(self):
        return len(self.unit_index)

    def shard_of(self, i):
        """The position (in ``dataset.shards``) of the shard holding item ``i``."""
        return self._shard[i]

    def group_of(self, i):
        """The row group (of its shard) holding item ``i``."""
        return self._group[i]

    def _decoded(self, k, g):
        if self._cache is None:  # made lazily, so each DataLoader worker process has its own
            self._cache = ShardCache(self.cache_shards)
        shard = self.dataset.shards[k]
        return self._cache.get((k, g), lambda: DecodedShard(self.dataset.read_row_group(shard, g, _wanted(self.columns), self._filter), extra=self.columns))

    def __getitem__(self, i):
        i = int(i)
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        k, g, unit = self._shard[i], self._group[i], self.unit_index[i]
        decoded = self._decoded(k, g)
        row = decoded.row_of.get(unit)
        if row is None:
            raise RuntimeError(f"shard {self.dataset.shards[k].path} has no unit {unit} any more: it changed since the index was built")
        return _as_tensors(decoded.pair(row)) if self.tensors else decoded.pair(row)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_cache"] = None  # decoded shards stay in the process that decoded them
        return state


def _wanted(columns):
    """The columns a pair is read from, then the extra ``columns``."""
    base = PAIR_COLUMNS + PROVENANCE_COLUMNS + ["target_scene_share"]
    return base + [c for c in columns if c not in base]


def _as_tensors(item):
    for key, value in item.items():
        if isinstance(value, np.ndarray):
            item[key] = _torch.from_numpy(value)
    return item


class StreamingPairDataset(_IterBase):
    """The selected pairs of a dataset, streamed for training: an iterable dataset (``torch.utils.data.
    IterableDataset``) that reads the committed shards one row group at a time (only the pair columns),
    each item a dict as ``PairDataset`` gives.

    Every pair is yielded exactly once per epoch across all distributed ranks × DataLoader workers: the
    row groups of the dataset (the same list on every rank, shuffled with ``seed + epoch`` when
    ``shuffle``) are dealt round-robin to the ``world_size × num_workers`` consumers, and each consumer
    shuffles its pairs through a buffer of ``buffer_size`` pairs (memory: about ``buffer_size`` × 0.2 MB).
    ``rank`` / ``world_size`` default to ``torch.distributed``'s when it is initialized, else 0 / 1; the
    worker comes from ``torch.utils.data.get_worker_info()``. Consumers get whole row groups, so their pair
    counts differ by up to a row group's (``output.row_group_rows``, 16 by default): with DistributedDataParallel, end the epoch on the
    shortest rank (e.g. ``torch.distributed.algorithms.join.Join``) or drop the remainder.

    Call ``set_epoch(e)`` before each epoch's iteration (with ``persistent_workers=False``, the default,
    each epoch's workers receive the new epoch). Selection arguments as ``PairDataset``.
    """

    def __init__(self, dataset, status="ok", scene=None, overlap_source=None, overlap_target=None, where=None,
                 tensors=False, columns=(), shuffle=True, buffer_size=256, seed=0, rank=None, world_size=None,
                 storage_options=None):
        if tensors and _torch is None:
            raise ImportError("StreamingPairDataset(tensors=True) needs torch (pip install torch)")
        if buffer_size < 1:
            raise ValueError("buffer_size must be at least 1")
        self.dataset = dataset if hasattr(dataset, "shards") else open_dataset(dataset, storage_options=storage_options)
        self.tensors = tensors
        self.columns = list(columns)
        self.shuffle = shuffle
        self.buffer_size = int(buffer_size)
        self.seed = int(seed)
        self.epoch = 0
        self.rank, self.world_size = rank, world_size
        self._filter = selection_expression(status, scene, overlap_source, overlap_target, where)
        #: (shard position, row group) of every row group of the committed shards, in file order.
        self.pieces = [(k, g) for k, shard in enumerate(self.dataset.shards) for g in range(len(self.dataset.row_groups(shard)))]

    def set_epoch(self, epoch):
        self.epoch = int(epoch)

    def consumer(self):
        """(this consumer's number, the number of consumers): rank-major over ranks × DataLoader workers."""
        rank, world = self.rank, self.world_size
        if world is None:
            dist = getattr(_torch, "distributed", None)
            ready = dist is not None and dist.is_available() and dist.is_initialized()
            rank, world = (dist.get_rank(), dist.get_world_size()) if ready else (0, 1)
        if not 0 <= rank < world:
            raise ValueError(f"rank {rank} is not in 0..{world - 1}")
        info = _torch.utils.data.get_worker_info() if _torch is not None else None
        worker, workers = (info.id, info.num_workers) if info is not None else (0, 1)
        return rank * workers + worker, world * workers

    def pieces_of(self, consumer, consumers):
        """The row groups consumer ``consumer`` of ``consumers`` reads this epoch, in reading order."""
        order = list(range(len(self.pieces)))
        if self.shuffle:
            random.Random(self.seed * 1_000_003 + self.epoch).shuffle(order)
        return [self.pieces[i] for i in order[consumer::consumers]]

    def __iter__(self):
        consumer, consumers = self.consumer()
        rng = random.Random((self.seed * 1_000_003 + self.epoch) * 65_537 + consumer)
        buffer = []
        for k, g in self.pieces_of(consumer, consumers):
            decoded = DecodedShard(self.dataset.read_row_group(self.dataset.shards[k], g, _wanted(self.columns), self._filter), extra=self.columns)
            for i in decoded.order:
                item = _as_tensors(decoded.pair(i)) if self.tensors else decoded.pair(i)
                if not self.shuffle:
                    yield item
                elif len(buffer) < self.buffer_size:
                    buffer.append(item)
                else:
                    j = rng.randrange(len(buffer))
                    buffer[j], item = item, buffer[j]
                    yield item
        rng.shuffle(buffer)
        yield from buffer


class ShardShuffleSampler:
    """Indices of a ``PairDataset`` in a shuffled order that reads each row group once per epoch: the shards
    in a random order, the row groups of each shard in a random order, the items of each row group
    shuffled. ``set_epoch(e)`` changes the order (the seed is ``seed + epoch``). Pass it as
    ``DataLoader(..., sampler=ShardShuffleSampler(ds))``; ``StreamingPairDataset`` is the faster path."""

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
            by_shard.setdefault(self.dataset.shard_of(i), {}).setdefault(self.dataset.group_of(i), []).append(i)
        shards = sorted(by_shard)
        rng.shuffle(shards)
        for k in shards:
            groups = sorted(by_shard[k])
            rng.shuffle(groups)
            for g in groups:
                items = by_shard[k][g]
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
    - ``target_known_share``, ``target_scene_share`` (sum M_b,) float32 and ``target_view`` (sum M_b,)
      int8, aligned with ``target_points``; ``None`` when a sample has no provenance (version-1 datasets);
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
        keys = [k for k, v in out.items() if isinstance(v, np.ndarray)]
        in_worker = _torch.utils.data.get_worker_info() is not None  # the batch goes to another process
        tensors = _one_storage([out[k] for k in keys]) if in_worker else [_torch.from_numpy(out[k]) for k in keys]
        out.update(zip(keys, tensors))
    for field in samples[0]:
        if field not in out:
            out[field] = [s[field] for s in samples]
    return out


def _one_storage(arrays):
    """Torch tensors equal to ``arrays``, all views of one storage. A DataLoader worker sends each storage
    of a batch through its own shared-memory segment; one storage instead of eleven made streaming into 2
    workers 1.5x as fast (docs/lab/2026-12-06-row-groups-and-scale.md). In the main process the copy only
    costs, so ``collate`` uses it in workers."""
    offsets, total = [], 0
    for a in arrays:
        offsets.append(total)
        total += (a.nbytes + 7) // 8 * 8  # every view starts 8-byte aligned
    buffer = np.empty(total, dtype=np.uint8)
    for a, o in zip(arrays, offsets):
        buffer[o:o + a.nbytes] = np.ascontiguousarray(a).reshape(-1).view(np.uint8)
    flat = _torch.from_numpy(buffer)
    return [flat[o:o + a.nbytes].view(_TORCH_DTYPES[a.dtype]).reshape(a.shape) for a, o in zip(arrays, offsets)]


_TORCH_DTYPES = {np.dtype(t): getattr(_torch, t) for t in ("float32", "float64", "int64", "int8")} if _torch is not None else {}


__all__ = ["PairDataset", "StreamingPairDataset", "ShardShuffleSampler", "collate", "INDEX_COLUMNS"]
