"""Datasets of pairs for ``torch.utils.data.DataLoader``: ``StreamingPairDataset`` (iterable: streams the
committed shards row group by row group, shuffled through a bounded buffer, split between workers and
ranks; the fast path for training), ``PairDataset`` (map-style: one item reads one row group), a
shard-aware sampler, and ``collate`` for clouds of different sizes. torch is optional: without it both are
plain classes (numpy samples), and ``collate`` returns numpy arrays.
"""

import random
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .dataset import (
    INDEX_COLUMNS, PAIR_COLUMNS, PAIR_FIELDS, PROVENANCE_COLUMNS, DecodedShard, ShardCache, field_columns, open_dataset,
    selection_expression,
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


def _fields(fields):
    """The pair fields to give: ``None`` for every one of ``PAIR_FIELDS``; ``unit_index`` always."""
    fields = PAIR_FIELDS if fields is None else tuple(fields)
    unknown = [f for f in fields if f not in PAIR_FIELDS]
    if unknown:
        raise KeyError(f"not pair fields: {unknown} (fields are {', '.join(PAIR_FIELDS)}; other columns go in columns=)")
    return fields if "unit_index" in fields else ("unit_index",) + fields


def _wanted(columns, fields=None):
    """The columns a pair is read from (those of ``fields``, default every pair field), then the extra ``columns``."""
    base = field_columns(_fields(fields))
    return base + [c for c in columns if c not in base]


def _filter_columns(status, scene, overlap_source, overlap_target, where):
    """The small columns the selection arguments read (all of ``INDEX_COLUMNS`` for a ``where``, whose
    fields are not known), ``unit_index`` first."""
    if where is not None:
        return list(INDEX_COLUMNS)
    cols = ["unit_index"]
    for name, value in (("status", status), ("scene", scene), ("overlap_source", overlap_source), ("overlap_target", overlap_target)):
        if value is not None:
            cols.append(name)
    return cols


def _selected_rows(dataset, shard, expr, columns=None):
    """(row positions in the file, unit indices) of the rows of ``shard`` that ``expr`` selects (every row
    when None): one read of the small columns of the whole shard (from a local copy when there is one,
    never a reason to make one)."""
    names = dataset.footer(shard).schema.to_arrow_schema().names
    cols = [c for c in (columns or INDEX_COLUMNS) if c in names] if expr is not None else ["unit_index"]
    t = dataset.read_groups(shard, range(len(dataset.group_rows(shard))), cols, copy="existing")
    t = t.append_column("__row", _pa().array(np.arange(t.num_rows, dtype=np.int64)))
    if expr is not None:
        t = t.filter(expr)
    return np.asarray(t.column("__row").to_numpy(), dtype=np.int64), np.asarray(t.column("unit_index").to_numpy(), dtype=np.int64)


def _pa():
    import pyarrow

    return pyarrow


class PairDataset(_Base):
    """The selected pairs of a dataset, indexable in unit order; each item is a dict (``PAIR_FIELDS`` of
    ``pointreggpt_data.dataset``): source/target points float32 (N, 3)/(M, 3), ``T_target_from_source``
    float64 (4, 4), both overlaps, the per-point provenance (``None`` for a version-1 dataset), pair key,
    scene, status, unit index and the unsigned seed.

    ``dataset``: a ``Dataset`` or a URL/path (opened with ``storage_options``). Selection: ``status``
    (default ``"ok"``; ``None`` for every row), ``scene``, ``overlap_source``/``overlap_target`` (inclusive
    ``(low, high)``), ``where`` (a ``pyarrow.compute`` expression over ``INDEX_COLUMNS``). ``tensors=True``
    returns torch tensors instead of numpy arrays. ``fields``: the pair fields to read and give (default
    every one; ``MINIMAL_FIELDS`` = the two clouds and the pose; ``unit_index`` always): only their
    columns are read and decoded, never the depth PNGs. ``columns``: more stored columns to return, as
    Python values (e.g. ``["source_intrinsics"]``). ``cache_groups``: decoded row groups kept per process
    (16 by default; ``cache_shards`` is its old name).

    An item reads and decodes its whole row group (at most the build's ``output.row_group_rows`` pairs, 16
    by default), through the shard's footer read once per process (``Dataset.footer``), and keeps it: a
    random order pays a row group per item; ``GroupShuffleSampler`` (random, reading each row group once
    per epoch and worker) or ``ShardShuffleSampler`` serve the other pairs of a group from the cache.
    Building the index reads only the unit indices (and the filter's small columns) of each shard once.
    """

    def __init__(self, dataset, status="ok", scene=None, overlap_source=None, overlap_target=None, where=None,
                 tensors=False, columns=(), cache_groups=16, storage_options=None, fields=None, cache_shards=None):
        if tensors and _torch is None:
            raise ImportError("PairDataset(tensors=True) needs torch (pip install torch)")
        self.dataset = dataset if hasattr(dataset, "shards") else open_dataset(dataset, storage_options=storage_options)
        self.tensors = tensors
        self.columns = list(columns)
        self.fields = _fields(fields)
        self.cache_groups = int(cache_shards if cache_shards is not None else cache_groups)
        self._filter = selection_expression(status, scene, overlap_source, overlap_target, where)
        small = _filter_columns(status, scene, overlap_source, overlap_target, where)
        units, shards, groups, rows = [], [], [], []
        # The small columns of every shard: on an object store, 8 shards at a time (their requests are
        # latency-bound); in a folder, one after the other.
        read = lambda shard: (self.dataset.group_rows(shard), _selected_rows(self.dataset, shard, self._filter, small))
        if self.dataset.remote and len(self.dataset.shards) > 1:
            with ThreadPoolExecutor(max_workers=8) as pool:
                selected = list(pool.map(read, self.dataset.shards))
        else:
            selected = [read(shard) for shard in self.dataset.shards]
        for k, (sizes, (positions, unit)) in enumerate(selected):
            starts = np.cumsum([0] + sizes)
            g = np.searchsorted(starts, positions, side="right") - 1
            units.append(unit)
            shards.append(np.full(len(unit), k, dtype=np.int32))
            groups.append(g.astype(np.int32))
            rows.append((positions - starts[g]).astype(np.int32))
        cat = lambda parts, t: np.concatenate(parts).astype(t) if parts else np.zeros(0, t)
        unit = cat(units, np.int64)
        order = np.argsort(unit.view(np.uint64) if unit.dtype == np.int64 else unit, kind="stable")
        #: Unit index, shard position, row group and row in the group of every item (unit order).
        self.unit_index = unit[order]
        self._shard = cat(shards, np.int32)[order]
        self._group = cat(groups, np.int32)[order]
        self._row = cat(rows, np.int32)[order]
        self._cache = None

    def __len__(self):
        return len(self.unit_index)

    def shard_of(self, i):
        """The position (in ``dataset.shards``) of the shard holding item ``i``."""
        return int(self._shard[i])

    def group_of(self, i):
        """The row group (of its shard) holding item ``i``."""
        return int(self._group[i])

    def groups(self):
        """Every item's (shard position, row group) as two int arrays, in item order (for samplers)."""
        return self._shard, self._group

    def _decoded(self, k, g):
        if self._cache is None:  # made lazily, so each DataLoader worker process has its own
            self._cache = ShardCache(self.cache_groups)
        shard = self.dataset.shards[k]
        return self._cache.get((k, g), lambda: DecodedShard(
            self.dataset.read_group(shard, g, _wanted(self.columns, self.fields)), extra=self.columns, fields=self.fields))

    def __getitem__(self, i):
        i = int(i)
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        k, g, row, unit = int(self._shard[i]), int(self._group[i]), int(self._row[i]), int(self.unit_index[i])
        decoded = self._decoded(k, g)
        if row >= decoded.n or decoded.unit_index[row] != unit:
            raise RuntimeError(f"shard {self.dataset.shards[k].path} has no unit {unit} at row {row} of group {g} any more: it changed since the index was built")
        return _as_tensors(decoded.pair(row)) if self.tensors else decoded.pair(row)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_cache"] = None  # decoded groups stay in the process that decoded them
        return state


def _as_tensors(item):
    for key, value in item.items():
        if isinstance(value, np.ndarray):
            item[key] = _torch.from_numpy(value)
    return item


def bounded_shuffle(items, size, rng):
    """Yields ``items`` shuffled through a buffer of ``size`` items, with a bound: the item that arrived
    ``a``-th (from 0) leaves as the ``o``-th with ``a - size <= o <= a + size``. The buffer holds ``size``
    items; each arrival sends out one of them at random, except that an item due (``o = a + size``)
    leaves first; at most one is due at a time, as arrivals are one apart, so the bound always holds.
    Unlike a plain random-replacement buffer, no item lingers to the end of the epoch."""
    if size < 1:
        raise ValueError("the shuffle buffer must hold at least 1 item")
    slots, where, held = [], {}, {}  # arrival numbers in the buffer; their positions in slots; the items
    out = 0

    def take():
        nonlocal out
        due = out - size
        a = due if due in held else slots[rng.randrange(len(slots))]
        j = where.pop(a)
        last = slots.pop()
        if last != a:
            slots[j] = last
            where[last] = j
        out += 1
        return held.pop(a)

    for a, item in enumerate(items):
        slots.append(a)
        where[a] = len(slots) - 1
        held[a] = item
        if len(slots) > size:
            yield take()
    while slots:
        yield take()


class StreamingPairDataset(_IterBase):
    """The selected pairs of a dataset, streamed for training: an iterable dataset (``torch.utils.data.
    IterableDataset``) that reads the committed shards a few row groups at a time (only the columns of
    ``fields``), each item a dict as ``PairDataset`` gives.

    Every pair is yielded exactly once per epoch across all distributed ranks × DataLoader workers: the
    pieces of the dataset (runs of consecutive row groups of one shard, of at most ``piece_rows`` rows or
    one group; the same list on every rank), shuffled with ``seed + epoch`` when ``shuffle``, are dealt
    round-robin to the ``world_size × num_workers`` consumers, and each consumer shuffles its pairs through
    a buffer of ``buffer_size`` pairs (``bounded_shuffle``: an item leaves at most ``buffer_size`` places
    from where it arrived; memory about ``buffer_size`` × 0.2 MB). ``rank`` / ``world_size`` default to
    ``torch.distributed``'s when it is initialized, else 0 / 1; the worker comes from
    ``torch.utils.data.get_worker_info()``. Consumers get whole pieces, so their pair counts differ by up
    to a piece: with DistributedDataParallel, end the epoch on the shortest rank (e.g.
    ``torch.distributed.algorithms.join.Join``) or drop the remainder.

    ``piece_rows``: the rows of a piece (default 16; on an object store without ``cache_dir``, whole
    shards: one request per shard, read whole; memory then about 3 shards' pair columns per consumer, and
    a consumer's pairs come shard by shard, mixed by the buffer). ``readahead``: pieces each consumer
    reads ahead on background threads (reading and decoding release the GIL; default 2, or 8 on an object
    store with ``cache_dir``, whose first reads fetch whole shards); 0 reads in the consuming thread. Call ``set_epoch(e)`` before each epoch's iteration (with
    ``persistent_workers=False``, the default, each epoch's workers receive the new epoch). Selection
    arguments and ``fields`` as ``PairDataset``.
    """

    def __init__(self, dataset, status="ok", scene=None, overlap_source=None, overlap_target=None, where=None,
                 tensors=False, columns=(), shuffle=True, buffer_size=256, seed=0, rank=None, world_size=None,
                 storage_options=None, fields=None, readahead=None, piece_rows=None):
        if tensors and _torch is None:
            raise ImportError("StreamingPairDataset(tensors=True) needs torch (pip install torch)")
        if buffer_size < 1:
            raise ValueError("buffer_size must be at least 1")
        self.dataset = dataset if hasattr(dataset, "shards") else open_dataset(dataset, storage_options=storage_options)
        self.tensors = tensors
        self.columns = list(columns)
        self.fields = _fields(fields)
        self.shuffle = shuffle
        self.buffer_size = int(buffer_size)
        self.seed = int(seed)
        self.epoch = 0
        self.rank, self.world_size = rank, world_size
        # On an object store without a local copy, whole shards: one request each (ranged reads of row
        # groups cost a request per group and column run, which a store's latency, or a local S3 server's
        # per-request cost, makes the limit); elsewhere runs of row groups of at most 16 rows.
        whole = self.dataset.remote and self.dataset.cache_dir is None
        if piece_rows is None:
            piece_rows = 1 << 62 if whole else 16
        self.readahead = (2 if whole else 8 if self.dataset.remote else 2) if readahead is None else int(readahead)
        self._filter = selection_expression(status, scene, overlap_source, overlap_target, where)
        self._filter_cols = _filter_columns(status, scene, overlap_source, overlap_target, where)
        #: (shard position, (row groups...)) of every piece: consecutive row groups of one shard holding at
        #: most ``piece_rows`` rows (or one group), in file order.
        self.pieces = []
        for k, shard in enumerate(self.dataset.shards):
            run, rows = [], 0
            for g, n in enumerate(self.dataset.group_rows(shard)):
                if run and rows + n > piece_rows:
                    self.pieces.append((k, tuple(run)))
                    run, rows = [], 0
                run.append(g)
                rows += n
            if run:
                self.pieces.append((k, tuple(run)))

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
        """The pieces consumer ``consumer`` of ``consumers`` reads this epoch, in reading order."""
        order = list(range(len(self.pieces)))
        if self.shuffle:
            random.Random(self.seed * 1_000_003 + self.epoch).shuffle(order)
        return [self.pieces[i] for i in order[consumer::consumers]]

    def _read(self, piece):
        k, groups = piece
        shard = self.dataset.shards[k]
        cols = _wanted(self.columns, self.fields)
        if self._filter is not None:
            cols += [c for c in self._filter_cols if c not in cols]
        ds = self.dataset  # a piece of every row group of a shard on an object store: one request for the object
        whole = ds.remote and ds.cache_dir is None and len(groups) == len(ds.group_rows(shard))
        table = ds.read_groups(shard, groups, cols, whole=whole)
        rows = None
        if self._filter is not None:  # the filter on the small columns only: filtering the table copies the clouds
            small = table.select([c for c in self._filter_cols if c in table.column_names])
            small = small.append_column("__row", _pa().array(np.arange(table.num_rows, dtype=np.int64)))
            rows = small.filter(self._filter).column("__row").to_numpy()
        return DecodedShard(table, extra=self.columns, fields=self.fields, rows=rows)

    def _decoded(self, pieces):
        if self.readahead <= 0:
            for piece in pieces:
                yield self._read(piece)
            return
        with ThreadPoolExecutor(max_workers=self.readahead) as pool:
            pending, it = [], iter(pieces)
            for piece in it:
                pending.append(pool.submit(self._read, piece))
                if len(pending) > self.readahead:
                    yield pending.pop(0).result()
            for f in pending:
                yield f.result()

    def _items(self, pieces):
        for decoded in self._decoded(pieces):
            for i in decoded.order:
                yield _as_tensors(decoded.pair(i)) if self.tensors else decoded.pair(i)

    def __iter__(self):
        consumer, consumers = self.consumer()
        items = self._items(self.pieces_of(consumer, consumers))
        if not self.shuffle:
            return items
        rng = random.Random((self.seed * 1_000_003 + self.epoch) * 65_537 + consumer)
        return bounded_shuffle(items, self.buffer_size, rng)


def _rank_world(rank, world_size):
    if world_size is None:
        dist = getattr(_torch, "distributed", None)
        ready = dist is not None and dist.is_available() and dist.is_initialized()
        return (dist.get_rank(), dist.get_world_size()) if ready else (0, 1)
    if not 0 <= rank < world_size:
        raise ValueError(f"rank {rank} is not in 0..{world_size - 1}")
    return rank, world_size


class GroupShuffleSampler:
    """Indices of a ``PairDataset`` in a random order that decodes each row group once per epoch: the
    sampler for random access (``DataLoader(pairs, batch_size=B, sampler=GroupShuffleSampler(pairs,
    batch_size=B, num_workers=W), ...)``).

    Each epoch (seed ``seed + epoch``) the row groups are shuffled and dealt round-robin to the distributed
    ranks (``rank``/``world_size``, default ``torch.distributed``'s when initialized: every pair exactly
    once per epoch across ranks, whose counts differ by up to a row group); a rank's groups are dealt to
    ``num_workers`` lanes (one per DataLoader worker, 1 for ``num_workers=0``); each lane takes ``mix``
    groups at a time (a window) and yields their pairs in a random order; and the lanes are interleaved
    ``batch_size`` items at a time, the order in which a DataLoader deals batches to its workers, so that
    the pairs of a group reach the worker that decoded it. ``PairDataset`` keeps the last ``cache_groups``
    decoded groups (16 by default): give it at least ``mix + 1``.

    What it does to randomness: every pair once per epoch and the order of the groups uniform, but a
    batch draws its pairs from the ``mix`` groups of one window (with ``mix`` ≥ the batch size, mostly
    one pair per group), and a window's pairs come out within ``mix × group rows`` places of each other.
    The pairs of a group are consecutive units (with ``samples_per_frame`` ≥ the group's rows, samples of
    one source frame), so ``mix=1`` puts the samples of one frame together in a batch; the default 8
    spreads a batch of 8 over about 8 groups for a cache of 16 decoded groups per worker (~70 MB with
    16-row groups). A fully random order (``RandomSampler``) decodes a whole row group for every pair.
    ``set_epoch(e)`` changes the order.
    """

    def __init__(self, dataset, batch_size=1, num_workers=0, mix=8, seed=0, rank=None, world_size=None):
        self.dataset = dataset
        self.batch_size = max(1, int(batch_size))
        self.lanes = max(1, int(num_workers))
        self.mix = max(1, int(mix))
        self.seed = int(seed)
        self.epoch = 0
        self.rank, self.world_size = rank, world_size

    def set_epoch(self, epoch):
        self.epoch = int(epoch)

    def _mine(self):
        """Every group's items (lists of item numbers), this rank's groups in this epoch's order."""
        shard, group = self.dataset.groups()
        shard, group = np.asarray(shard, dtype=np.int64), np.asarray(group, dtype=np.int64)
        key = (shard << 32) | group
        order = np.argsort(key, kind="stable")
        uniq, starts = np.unique(key[order], return_index=True)
        bounds = list(starts) + [len(order)]
        members = [order[bounds[j]:bounds[j + 1]].tolist() for j in range(len(uniq))]
        rng = random.Random(self.seed * 1_000_003 + self.epoch)
        rng.shuffle(members)
        rank, world = _rank_world(self.rank, self.world_size)
        return members[rank::world], rng

    def __len__(self):
        return sum(len(m) for m in self._mine()[0])

    def __iter__(self):
        members, rng = self._mine()
        lanes = []
        for lane in range(self.lanes):
            groups = members[lane::self.lanes]
            items = []
            for j in range(0, len(groups), self.mix):
                window = [i for g in groups[j:j + self.mix] for i in g]
                rng.shuffle(window)
                items.extend(window)
            lanes.append(items)
        pos = [0] * self.lanes
        lane = 0
        while any(p < len(items) for p, items in zip(pos, lanes)):
            if pos[lane] < len(lanes[lane]):
                chunk = lanes[lane][pos[lane]:pos[lane] + self.batch_size]
                pos[lane] += len(chunk)
                yield from chunk
            lane = (lane + 1) % self.lanes


class ShardShuffleSampler:
    """Indices of a ``PairDataset`` in a shuffled order that reads each row group once per epoch: the shards
    in a random order, the row groups of each shard in a random order, the items of each row group
    shuffled. ``set_epoch(e)`` changes the order (the seed is ``seed + epoch``). Pass it as
    ``DataLoader(..., sampler=ShardShuffleSampler(ds))``; ``GroupShuffleSampler`` mixes more and fits
    DataLoader workers; ``StreamingPairDataset`` is the faster path."""

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
    first = samples[0]
    as_torch = _torch is not None and any(isinstance(v, _torch.Tensor) for v in first.values())
    to_np = (lambda x: x.numpy()) if as_torch else np.asarray
    # Each array of the batch as (key, dtype, shape, fill): made in one pass once every size is known,
    # so that in a DataLoader worker they can all be written straight into one shared-memory block.
    plan, out = [], {}
    n = len(samples)
    for cloud in ("source", "target"):
        if f"{cloud}_points" not in first:  # not among the dataset's fields
            continue
        lengths = np.array([len(s[f"{cloud}_points"]) for s in samples], dtype=np.int64)
        plan.append((f"{cloud}_lengths", np.int64, (n,), lambda o, v=lengths: np.copyto(o, v)))
        plan.append((f"{cloud}_batch", np.int64, (int(lengths.sum()),),
                     lambda o, v=lengths: np.copyto(o, np.repeat(np.arange(n, dtype=np.int64), v))))
    for field, _ in _POINT_FIELDS:
        if field not in first:
            continue
        values = [s.get(field) for s in samples]
        if any(v is None for v in values):
            out[field] = None
            continue
        values = [to_np(v) for v in values]
        shape = (sum(len(v) for v in values),) + values[0].shape[1:]
        plan.append((field, values[0].dtype, shape, lambda o, v=values: np.concatenate(v, axis=0, out=o)))
    if "T_target_from_source" in first:
        values = [to_np(s["T_target_from_source"]) for s in samples]
        plan.append(("T_target_from_source", np.float64, (n, 4, 4), lambda o, v=values: np.stack(v, out=o)))
    for field in ("overlap_source", "overlap_target"):
        if field in first:
            plan.append((field, np.float64, (n,), lambda o, f=field: np.copyto(o, [s[f] for s in samples])))
    if "unit_index" in first:
        plan.append(("unit_index", np.int64, (n,), lambda o: np.copyto(o, [s["unit_index"] for s in samples])))
    in_worker = as_torch and _torch.utils.data.get_worker_info() is not None  # the batch goes to another process
    arrays = _shared_arrays(plan) if in_worker else [np.empty(shape, dtype) for _, dtype, shape, _ in plan]
    for (key, _, _, fill), array in zip(plan, arrays):
        fill(array)
        out[key] = array
    if as_torch:
        keys = [key for key, _, _, _ in plan]
        out.update((k, out[k] if isinstance(out[k], _torch.Tensor) else _torch.from_numpy(out[k])) for k in keys)
        if in_worker:
            out.update(zip(keys, arrays.tensors))
    for field in samples[0]:
        if field not in out:
            out[field] = [s[field] for s in samples]
    return out


class _SharedArrays(list):
    """numpy views of one shared-memory block, with the torch tensors over the same bytes (``tensors``)."""


def _shared_arrays(plan):
    """Empty arrays of ``plan``'s dtypes and shapes, all in one block of shared memory (8-byte aligned
    views), for a batch a DataLoader worker sends to the main process: torch sends a storage that is
    already shared as its handle, without copying it, and one block costs one segment instead of one per
    array. Streaming into 2 workers was 1.5x as fast with one storage
    (docs/lab/2026-12-06-row-groups-and-scale.md); writing the batch into shared memory directly saves
    the copy that sharing made on top."""
    offsets, total = [], 0
    for _, dtype, shape, _ in plan:
        offsets.append(total)
        total += (int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize + 7) // 8 * 8
    flat = _torch.empty(0, dtype=_torch.uint8)
    flat.set_(_torch.UntypedStorage._new_shared(max(total, 8)))
    out = _SharedArrays()
    out.tensors = []
    for (_, dtype, shape, _), o in zip(plan, offsets):
        size = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
        t = flat[o:o + size].view(_TORCH_DTYPES[np.dtype(dtype)]).reshape(shape)
        out.tensors.append(t)
        out.append(t.numpy())
    return out


_TORCH_DTYPES = {np.dtype(t): getattr(_torch, t) for t in ("float32", "float64", "int64", "int8")} if _torch is not None else {}


__all__ = ["PairDataset", "StreamingPairDataset", "GroupShuffleSampler", "ShardShuffleSampler", "bounded_shuffle", "collate", "INDEX_COLUMNS"]
