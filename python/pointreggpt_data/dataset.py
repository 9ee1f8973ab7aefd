"""The committed pairs of a pointreggpt dataset: manifest, schema versions, filters, shard-by-shard reads.

Only the shard files named by ``<dataset>/manifest/pairs-<shard>.json`` entries (their ``file`` field,
under ``shards/``) are part of a dataset; other files in ``shards/`` (a shard being written, a writer
that lost a race on an object store) are never read.

Schema versions (``schemas/pairs-v3.md``, ``pairs-v2.md``, ``pairs-v1.md`` in the pointreggpt repository):
``pairs/3`` adds the scene to ``pairs/2``: ``scene_frames`` (int32) and the per-point
``target_scene_share`` (float32), the share of a target point's voxel that the posed frames around the
source saw. ``pairs/2`` stores every integer signed, the 64-bit ``seed`` bit for bit as ``int64`` (negative
at or above 2**63), and the per-point provenance lists ``target_known_share`` (float32) and ``target_view``
(int8), aligned with ``target_points``. ``pairs/1`` stores unsigned integers and has no provenance. This
module gives the same Python values for all: ``unit_index`` and the unsigned ``seed`` as Python ints,
``None`` provenance for version 1, and scene shares of 0 for version 2 (exact: it had no scene).
"""

import hashlib
import json
import os
import pickle
import posixpath
import re
import threading
from collections import OrderedDict

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as pads
import pyarrow.fs as pafs
import pyarrow.parquet as pq

from .store import filesystem_for

TABLE = "pairs"
SCHEMA_VERSION_KEY = b"schema_version"
U64 = (1 << 64) - 1

#: Small columns read to select rows; ``where=`` expressions may use any of them.
INDEX_COLUMNS = [
    "unit_index", "pair_key", "scene", "frame_key", "sample_index", "status", "seed",
    "width", "height", "pose_draws", "overlap_source", "overlap_target",
]
#: Columns a pair (``Dataset.pairs``, ``PairDataset``) is made of; provenance only where the shard has it.
PAIR_COLUMNS = [
    "unit_index", "pair_key", "scene", "status", "seed", "t_target_from_source",
    "source_points", "target_points", "overlap_source", "overlap_target",
]
PROVENANCE_COLUMNS = ["target_known_share", "target_view"]
#: Columns version 3 added (read where a shard has them).
SCENE_COLUMNS = ["target_scene_share", "scene_frames"]
#: The stored column of each pair field (the others are stored under their own name).
FIELD_COLUMNS = {"T_target_from_source": "t_target_from_source"}
#: Fields a trainer that only registers clouds needs (``fields=MINIMAL_FIELDS``): the clouds and the pose.
MINIMAL_FIELDS = ("source_points", "target_points", "T_target_from_source")
#: The schema versions this reader knows.
SCHEMA_VERSIONS = ("pairs/1", "pairs/2", "pairs/3")
STATUSES = ("ok", "low_overlap", "too_few_points", "input_error")


class DatasetError(RuntimeError):
    """Not a readable pointreggpt dataset (no dataset.toml, a bad manifest entry, an unknown schema)."""


def open_dataset(url, storage_options=None, filesystem=None, cache_dir=None, footer_cache=1024):
    """The dataset at ``url`` (a folder, ``s3://bucket/prefix``, ``az://container/prefix``, ``gs://...``).

    ``storage_options``: explicit credentials and endpoint (``pointreggpt_data.store``); ``filesystem``: a
    ready ``pyarrow.fs.FileSystem`` (``url`` is then the path in it). ``cache_dir``: on an object store,
    the row-group reads of the training loaders copy each whole shard file there on its first read (named
    by its blake3, so a rebuilt dataset never reads a stale copy) and read the copy from then on; a local
    dataset ignores it. ``footer_cache``: how many shards' parsed footers each process keeps.
    """
    return Dataset(url, storage_options=storage_options, filesystem=filesystem, cache_dir=cache_dir, footer_cache=footer_cache)


def unsigned_seed(value):
    """A stored seed (version 2: ``int64`` bit for bit; version 1: ``uint64``) as the unit's unsigned seed."""
    return int(value) & U64


def points_array(column, row):
    """Row ``row`` of a ``list<fixed_size_list<float32, 3>>`` column as a float32 (N, 3) numpy array
    (a copy of the stored bits, never converted through float64)."""
    lst = column[row] if isinstance(column, (pa.ChunkedArray, pa.Array)) else column
    values = lst.values
    if values is None or len(values) == 0:
        return np.zeros((0, 3), np.float32)
    flat = values.flatten()
    return np.array(flat.to_numpy(zero_copy_only=False), dtype=np.float32).reshape(-1, 3)


def _flat_points(list_array):
    """Every point of the rows of a points ``ListArray`` and each row's offsets into them:
    (float32 (P, 3), int64 (n + 1,) starting at 0). Slicing of the array is respected."""
    offsets = np.asarray(list_array.offsets, dtype=np.int64)
    flat = np.asarray(list_array.flatten().flatten().to_numpy(zero_copy_only=False), dtype=np.float32)
    return flat.reshape(-1, 3), offsets - offsets[0]


def _flat_values(list_array, dtype):
    """The values of the rows of a ``ListArray`` of scalars and each row's offsets into them."""
    offsets = np.asarray(list_array.offsets, dtype=np.int64)
    return np.asarray(list_array.flatten().to_numpy(zero_copy_only=False), dtype=dtype), offsets - offsets[0]


def _range_expr(name, bounds):
    """``lo <= name <= hi`` for ``bounds = (lo, hi)`` (either may be None); None for no bounds."""
    if bounds is None:
        return None
    if isinstance(bounds, (int, float)):
        raise TypeError(f"{name}: give a (low, high) range, e.g. ({bounds}, None) for at least {bounds}")
    lo, hi = bounds
    e = None
    if lo is not None:
        e = pc.field(name) >= float(lo)
    if hi is not None:
        h = pc.field(name) <= float(hi)
        e = h if e is None else e & h
    return e


def selection_expression(status="ok", scene=None, overlap_source=None, overlap_target=None, where=None):
    """The row filter of the selection arguments as one ``pyarrow.compute.Expression`` (None: every row).

    ``status``: a status or a list of them (``None``: every status); ``scene``: a scene or a list;
    ``overlap_source`` / ``overlap_target``: inclusive ``(low, high)`` ranges, either end ``None``;
    ``where``: any further ``pyarrow.compute`` expression over ``INDEX_COLUMNS`` (e.g.
    ``pc.field("sample_index") == 0``)."""
    parts = []
    for name, value in (("status", status), ("scene", scene)):
        if value is None:
            continue
        if isinstance(value, str):
            parts.append(pc.field(name) == value)
        else:
            parts.append(pc.field(name).isin(list(value)))
    for name, bounds in (("overlap_source", overlap_source), ("overlap_target", overlap_target)):
        e = _range_expr(name, bounds)
        if e is not None:
            parts.append(e)
    if where is not None:
        if not isinstance(where, pc.Expression):
            raise TypeError("where= takes a pyarrow.compute.Expression, e.g. pc.field('sample_index') == 0")
        parts.append(where)
    if not parts:
        return None
    expr = parts[0]
    for p in parts[1:]:
        expr = expr & p
    return expr


class Shard:
    """One committed shard: its manifest entry, its file's path in the store, and its schema version."""

    def __init__(self, entry, path, schema_version):
        self.entry = entry
        self.index = entry["shard"]
        self.path = path
        self.rows = entry["rows"]
        self.schema_version = schema_version
        self._fragment = None
        self._groups = None

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_fragment"] = None  # re-made (and its footer re-read) in the process that unpickles it
        state["_groups"] = None
        return state

    @property
    def blake3(self):
        """The blake3 of the shard's file, from its manifest entry ("" when the entry has none)."""
        return str(self.entry.get("blake3", ""))

    def __repr__(self):
        return f"Shard({self.index}, {self.path!r}, rows={self.rows}, {self.schema_version})"


class Dataset:
    """A pointreggpt dataset opened for reading (see ``open_dataset``).

    Attributes: ``url``, ``filesystem`` and ``base`` (the dataset's path in it), ``schema_version``
    (``"pairs/3"``, ``"pairs/2"`` or ``"pairs/1"``, from ``dataset.toml``), ``has_provenance``, ``config_hash``,
    ``shards`` (the committed shards in shard order), ``num_rows`` (rows of the committed shards).
    """

    def __init__(self, url, storage_options=None, filesystem=None, cache_dir=None, footer_cache=1024):
        self.url = str(url)
        self.storage_options = dict(storage_options or {})
        self.filesystem, self.base = filesystem_for(url, storage_options, filesystem)
        #: An object store (anything but the local filesystem): reads are pre-buffered and may be cached.
        self.remote = not isinstance(self.filesystem, pafs.LocalFileSystem)
        #: Where whole shard files of an object store are copied on first read (None: read them in place).
        self.cache_dir = os.path.abspath(os.fspath(cache_dir)) if cache_dir is not None else None
        self.footer_cache = max(1, int(footer_cache))
        self._footers = OrderedDict()
        self._lock = threading.Lock()
        self._copying = {}
        header = self._read_header()
        self.schema_version = header.get("schema_version", "")
        self.config_hash = header.get("config_hash", "")
        self.code_version = header.get("code_version", "")
        if self.schema_version not in SCHEMA_VERSIONS:
            raise DatasetError(
                f"{self.url}: the dataset's schema is {self.schema_version!r}; this reader knows {', '.join(SCHEMA_VERSIONS)}"
            )
        self.has_provenance = self.schema_version != "pairs/1"
        self.shards = self._read_manifest()
        self.num_rows = sum(s.rows for s in self.shards)
        self._pid = os.getpid()

    # -- layout -----------------------------------------------------------------------------------------

    def _path(self, *parts):
        return posixpath.join(self.base, *parts) if self.base != "/" else "/" + posixpath.join(*parts)

    def _read_text(self, path):
        with self.filesystem.open_input_stream(path) as f:
            return f.read().decode("utf-8")

    def _read_header(self):
        path = self._path("dataset.toml")
        info = self.filesystem.get_file_info(path)
        if info.type != pafs.FileType.File:
            raise DatasetError(f"{self.url}: not a pointreggpt dataset: it has no dataset.toml")
        header = {}
        # The header is dotted `dataset.<key> = "<value>"` lines before every table.
        for line in self._read_text(path).splitlines():
            m = re.match(r'^\s*dataset\.(\w+)\s*=\s*"((?:[^"\\]|\\.)*)"\s*$', line)
            if m:
                header[m.group(1)] = json.loads('"' + m.group(2) + '"')
            elif line.startswith("["):
                break
        if "schema_version" not in header:
            raise DatasetError(f"{self.url}: dataset.toml has no dataset.schema_version header")
        return header

    def _read_manifest(self):
        selector = pafs.FileSelector(self._path("manifest"), allow_not_found=True)
        shards = []
        for info in self.filesystem.get_file_info(selector):
            name = info.base_name
            if info.type != pafs.FileType.File or not (name.startswith(TABLE + "-") and name.endswith(".json")):
                continue
            try:
                entry = json.loads(self._read_text(info.path))
                file = entry["file"]
                entry["shard"], entry["rows"] = int(entry["shard"]), int(entry["rows"])
            except (ValueError, KeyError, TypeError) as e:
                raise DatasetError(f"{self.url}: bad manifest entry {name}: {e}") from None
            if entry.get("table", TABLE) != TABLE or "/" in file or not file.startswith(TABLE + "-"):
                raise DatasetError(f"{self.url}: manifest entry {name} names {file!r}, not a {TABLE} shard")
            version = entry.get("schema_version") or self.schema_version
            shards.append(Shard(entry, self._path("shards", file), version))
        shards.sort(key=lambda s: s.index)
        return shards

    @property
    def files(self):
        """The committed shard files (paths in ``filesystem``), in shard order."""
        return [s.path for s in self.shards]

    def __repr__(self):
        return f"Dataset({self.url!r}, {self.schema_version}, {len(self.shards)} shards, {self.num_rows} rows)"

    # -- reading ----------------------------------------------------------------------------------------

    def _check_process(self):
        """In a process forked after this dataset was opened (a DataLoader worker with the default "fork"
        start on Linux), a fresh filesystem client and fragments: a store client's pooled connections must
        not be shared with the parent. Azure's SDK keeps its connection pool process-wide, so a forked
        process cannot get a clean one: refused with the remedy (spawned workers unpickle the dataset,
        which makes a new client; see ``__setstate__``)."""
        if self._pid == os.getpid():
            return
        azure = getattr(pafs, "AzureFileSystem", None)
        if azure is not None and isinstance(self.filesystem, azure):
            raise DatasetError(
                f"{self.url}: an az:// dataset cannot be read in a forked process (the Azure SDK's connection pool "
                "is shared with the parent and mixes up responses): give the DataLoader multiprocessing_context='spawn' "
                "(or 'forkserver'), or num_workers=0"
            )
        self.filesystem = pickle.loads(pickle.dumps(self.filesystem))  # pyarrow filesystems rebuild from their options
        for s in self.shards:
            s._fragment = None
            s._groups = None
        self._lock = threading.Lock()  # a lock held by a thread of the parent at the fork would never be released
        self._copying = {}
        self._pid = os.getpid()

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_footers"] = OrderedDict()  # parsed footers stay in the process that read them
        state["_lock"] = None
        state["_copying"] = {}
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._lock = threading.Lock()
        self._pid = os.getpid()  # unpickled: the filesystem client was just made in this process

    def fragment(self, shard):
        """The shard's ``pyarrow.dataset`` fragment; its footer is read once and kept, so each later read
        of the shard fetches only the column chunks it needs."""
        self._check_process()
        if shard._fragment is None:
            fragment = pads.ParquetFileFormat().make_fragment(shard.path, filesystem=self.filesystem)
            fragment.ensure_complete_metadata()
            shard._fragment = fragment
        return shard._fragment

    def row_groups(self, shard):
        """The shard's row groups as ``pyarrow.dataset`` fragments, in file order (from its footer, read once):
        the smallest piece of a shard that is read on its own."""
        if shard._groups is None:
            shard._groups = self.fragment(shard).split_by_row_group()
        return shard._groups

    def read_row_group(self, shard, group, columns, filter=None):
        """As ``read_shard``, for row group ``group`` of the shard only."""
        names = self.shard_schema(shard).names
        cols = [c for c in columns if c in names]
        return self.row_groups(shard)[group].to_table(columns=cols, filter=filter)

    # -- row groups through cached footers (the training loaders' path) ---------------------------------

    def _source(self, shard, copy):
        """(filesystem, path) to read ``shard`` from: on an object store with a ``cache_dir``, the local copy
        (``copy=True``: made first if missing; ``"existing"``: only if it is already there), else the shard
        in its store."""
        if copy and self.remote and self.cache_dir is not None:
            if copy != "existing":
                return pafs.LocalFileSystem(), self.cached_copy(shard)
            local = self._copy_path(shard)
            if self._complete(shard, local):
                return pafs.LocalFileSystem(), local
        return self.filesystem, shard.path

    def _copy_path(self, shard):
        name = shard.blake3 or hashlib.sha256(self.url.encode()).hexdigest()[:16] + "-" + posixpath.basename(shard.path)[:-8]
        return os.path.join(self.cache_dir, name + ".parquet")

    @staticmethod
    def _complete(shard, path):
        want = shard.entry.get("bytes")
        return os.path.exists(path) and (want is None or os.path.getsize(path) == int(want))

    def cached_copy(self, shard):
        """The path of the shard's local copy in ``cache_dir``, downloaded first if it is not there (whole,
        in ranged reads of 64 MB, into a temporary name renamed when complete: concurrent readers never see
        a partial file; one download per shard per process). Named by the manifest's blake3 and checked
        against its byte count."""
        path = self._copy_path(shard)
        want = shard.entry.get("bytes")
        if self._complete(shard, path):
            return path
        with self._lock:  # one download per shard in this process, however many threads ask for it
            lock = self._copying.setdefault(shard.index, threading.Lock())
        with lock:
            if not self._complete(shard, path):
                self._download(shard, path, want)
        return path

    def _download(self, shard, path, want):
        os.makedirs(self.cache_dir, exist_ok=True)
        tmp = f"{path}.{os.getpid()}-{threading.get_ident()}.part"
        try:
            with self.filesystem.open_input_file(shard.path) as src, open(tmp, "wb") as dst:
                size, done = src.size(), 0
                while done < size:  # ranged reads of 64 MB (an input stream's reads would be many small requests)
                    block = src.read_at(min(64 << 20, size - done), done)
                    dst.write(block)
                    done += len(block)
            if want is not None and os.path.getsize(tmp) != int(want):
                raise DatasetError(f"{shard.path}: copied {os.path.getsize(tmp)} bytes, the manifest says {want}")
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.remove(tmp)

    def footer(self, shard, copy=True):
        """The shard's parsed Parquet footer (``pyarrow.parquet.FileMetaData``), read once per process and
        kept (the last ``footer_cache`` shards): a row-group read then fetches only its column chunks."""
        self._check_process()
        with self._lock:
            meta = self._footers.get(shard.index)
            if meta is not None:
                self._footers.move_to_end(shard.index)
                return meta
        # From the local copy when there is one; never a reason to download the whole shard (its footer
        # is the store's, byte for byte).
        fs, path = self._source(shard, "existing" if copy else False)
        with fs.open_input_file(path) as f:
            meta = pq.ParquetFile(f).metadata
        with self._lock:
            self._footers[shard.index] = meta
            while len(self._footers) > self.footer_cache:
                self._footers.popitem(last=False)
        return meta

    def group_rows(self, shard):
        """The number of rows of each row group of the shard, in file order (from its footer)."""
        meta = self.footer(shard)
        return [meta.row_group(g).num_rows for g in range(meta.num_row_groups)]

    def read_groups(self, shard, groups, columns, copy=True, whole=False):
        """The columns ``columns`` (those the shard has) of the row groups ``groups`` (a list, in that order)
        of one shard, every row: one open of the file with its cached footer, only those column chunks
        read and decoded (on an object store, pre-buffered: the chunks are fetched in a few concurrent,
        coalesced requests; ``whole``: the whole object in one request). Safe to call from several threads
        at once."""
        meta = self.footer(shard, copy)
        names = meta.schema.to_arrow_schema().names
        cols = [c for c in columns if c in names]
        fs, path = self._source(shard, copy)
        groups = list(groups)
        if whole and fs is self.filesystem and self.remote:
            # ``whole``: on an object store, the whole object in one request (a shard is tens of MB; one
            # GET instead of a few ranged ones per row group and column run), for a read of most of it.
            with fs.open_input_file(path) as f:  # read_at: one request (an input stream's read() makes many)
                data = pa.BufferReader(f.read_at(f.size(), 0))
            return pq.ParquetFile(data, metadata=meta).read_row_groups(groups, columns=cols, use_threads=False)
        with fs.open_input_file(path) as f:
            reader = pq.ParquetFile(f, metadata=meta, pre_buffer=self.remote and fs is self.filesystem)
            return reader.read_row_groups(groups, columns=cols, use_threads=False)

    def read_group(self, shard, group, columns, copy=True):
        """As ``read_groups`` for one row group."""
        return self.read_groups(shard, [group], columns, copy)

    def shard_schema(self, shard):
        """The Arrow schema of a shard's file (from its footer, read once)."""
        return self.fragment(shard).physical_schema

    def shard_has_provenance(self, shard):
        return all(c in self.shard_schema(shard).names for c in PROVENANCE_COLUMNS)

    def read_shard(self, shard, columns, filter=None):
        """The columns ``columns`` of one committed shard (only those, and the columns ``filter`` uses, are
        read), rows in file order, keeping those where ``filter`` (a ``pyarrow.compute`` expression) holds.
        Columns an older shard lacks (provenance in version 1, the scene before version 3) are left out."""
        names = self.shard_schema(shard).names
        cols = [c for c in columns if c in names]
        unknown = [c for c in columns if c not in names and c not in PROVENANCE_COLUMNS + SCENE_COLUMNS]
        if unknown:
            raise KeyError(f"{shard.path}: no column(s) {unknown} (columns: {', '.join(names)})")
        return self.fragment(shard).to_table(columns=cols, filter=filter)

    def tables(self, columns=None, status="ok", scene=None, overlap_source=None, overlap_target=None, where=None):
        """Yields ``(shard, pyarrow.Table)`` shard by shard: the selected rows (``selection_expression``) of
        each committed shard with only ``columns`` (default ``INDEX_COLUMNS``) read."""
        expr = selection_expression(status, scene, overlap_source, overlap_target, where)
        for shard in self.shards:
            yield shard, self.read_shard(shard, columns or INDEX_COLUMNS, expr)

    def to_table(self, columns=None, status="ok", scene=None, overlap_source=None, overlap_target=None, where=None):
        """The selected rows of every committed shard as one ``pyarrow.Table`` (``columns`` only), in shard
        order. Version-1 and version-2 shards are not mixed in one dataset."""
        parts = [t for _, t in self.tables(columns, status, scene, overlap_source, overlap_target, where)]
        if not parts:
            return pa.table({c: [] for c in (columns or INDEX_COLUMNS)})
        return pa.concat_tables(parts)

    def pair_keys(self, status="ok", scene=None, overlap_source=None, overlap_target=None, where=None):
        """The pair keys of the selected rows in unit order."""
        t = self.to_table(["unit_index", "pair_key"], status, scene, overlap_source, overlap_target, where)
        order = np.argsort(np.asarray(t.column("unit_index").to_numpy(), dtype=np.uint64), kind="stable")
        keys = t.column("pair_key").to_pylist()
        return [keys[i] for i in order]

    def pairs(self, status="ok", scene=None, overlap_source=None, overlap_target=None, where=None, columns=()):
        """Yields each selected pair as a dict (``PAIR_FIELDS``), shard by shard in unit order, reading
        the pair columns (plus ``columns``, returned as Python values) of one shard at a time."""
        expr = selection_expression(status, scene, overlap_source, overlap_target, where)
        base = PAIR_COLUMNS + PROVENANCE_COLUMNS + ["target_scene_share"]
        wanted = base + [c for c in columns if c not in base]
        for shard in self.shards:
            decoded = DecodedShard(self.read_shard(shard, wanted, expr), extra=columns)
            for i in decoded.order:
                yield decoded.pair(i)


#: The fields of a pair dict (``Dataset.pairs``, ``PairDataset``):
#:
#: ``pair_key`` str, ``scene`` str, ``status`` str, ``unit_index`` int, ``seed`` int (the unit's unsigned
#: 64-bit seed), ``source_points`` float32 (N, 3) in the source camera frame, ``target_points`` float32
#: (M, 3) in the target camera frame, ``T_target_from_source`` float64 (4, 4) (``p_t = R p_s + t``),
#: ``overlap_source`` / ``overlap_target`` float, ``target_known_share`` float32 (M,), ``target_scene_share``
#: float32 (M,) and ``target_view`` int8 (M,) (``None`` in a version-1 dataset; the scene shares 0 in a
#: version-2 one). A point's made-up share is ``1 - known - scene``.
PAIR_FIELDS = (
    "pair_key", "scene", "status", "unit_index", "seed", "source_points", "target_points",
    "T_target_from_source", "overlap_source", "overlap_target", "target_known_share", "target_scene_share",
    "target_view",
)


def field_columns(fields):
    """The stored columns the pair fields ``fields`` are read from (``target_scene_share`` brings
    ``target_known_share`` along: a version-2 shard has no scene column, and its zeros follow the known
    shares' lengths)."""
    cols = []
    for f in fields:
        if f not in PAIR_FIELDS:
            raise KeyError(f"{f!r} is not a pair field ({', '.join(PAIR_FIELDS)}); other columns go in columns=")
        c = FIELD_COLUMNS.get(f, f)
        if c not in cols:
            cols.append(c)
        if f == "target_scene_share" and "target_known_share" not in cols:
            cols.append("target_known_share")
    return cols


class DecodedShard:
    """Rows of pair columns (a shard, a row group) decoded once into flat numpy buffers; ``pair(i)``
    slices row ``i``. ``fields``: the pair fields to give (default every one of ``PAIR_FIELDS``); the
    table must hold their columns (``field_columns``), and may lack the provenance (version 1) or the
    scene share (version 2). ``extra``: more columns, given as Python values. ``rows``: the rows to give
    (``order``; default every one), e.g. those a filter selected (decoding them all and choosing costs less
    than filtering the table's list columns)."""

    def __init__(self, table, extra=(), fields=None, rows=None):
        self.n = table.num_rows
        self.fields = tuple(PAIR_FIELDS if fields is None else fields)
        want = set(self.fields)
        names = set(table.column_names)
        col = lambda name: table.column(name).combine_chunks() if table.num_rows else table.column(name)
        self.pair_key = table.column("pair_key").to_pylist() if "pair_key" in want else None
        self.scene = table.column("scene").to_pylist() if "scene" in want else None
        self.status = table.column("status").to_pylist() if "status" in want else None
        self.unit_index = [int(u) for u in table.column("unit_index").to_pylist()] if "unit_index" in names else None
        self.seed = [unsigned_seed(s) for s in table.column("seed").to_pylist()] if "seed" in want else None
        self.overlap_source = table.column("overlap_source").to_numpy().astype(np.float64) if "overlap_source" in want else None
        self.overlap_target = table.column("overlap_target").to_numpy().astype(np.float64) if "overlap_target" in want else None
        self.transform = self.source = self.target = None
        if self.n and "T_target_from_source" in want:
            t = col("t_target_from_source")
            self.transform = np.asarray(t.flatten().to_numpy(zero_copy_only=False), dtype=np.float64).reshape(self.n, 4, 4)
        if self.n and "source_points" in want:
            self.source, self.source_off = _flat_points(col("source_points"))
        if self.n and "target_points" in want:
            self.target, self.target_off = _flat_points(col("target_points"))
        # Version 1 has no provenance column; version 2 has no scene share (its zeros follow the known shares).
        self.provenance = any(c in names for c in PROVENANCE_COLUMNS + ["target_scene_share"])
        self.known = self.scene_share = self.view = None
        if self.provenance and self.n:
            aligned = []
            if "target_known_share" in names:
                self.known, self.known_off = _flat_values(col("target_known_share"), np.float32)
                aligned.append(self.known_off)
            if "target_view" in want and "target_view" in names:
                self.view, self.view_off = _flat_values(col("target_view"), np.int8)
                aligned.append(self.view_off)
            if "target_scene_share" in want:
                if "target_scene_share" in names:
                    self.scene_share, self.scene_off = _flat_values(col("target_scene_share"), np.float32)
                else:  # version 2: no scene
                    self.scene_share, self.scene_off = np.zeros(len(self.known), dtype=np.float32), self.known_off
                aligned.append(self.scene_off)
            if self.target is not None:
                aligned.append(self.target_off)
            if any(not np.array_equal(o, aligned[0]) for o in aligned[1:]):
                keys = table.column("pair_key").to_pylist() if "pair_key" in names else list(range(self.n))
                bad = [keys[i] for i in range(self.n) if len({int(o[i + 1] - o[i]) for o in aligned}) != 1]
                raise DatasetError(f"provenance lists not aligned with target_points in pair(s) {bad[:5]}")
        self.extra = {c: table.column(c).to_pylist() for c in extra}
        chosen = range(self.n) if rows is None else [int(r) for r in rows]
        if self.unit_index is not None:
            self.order = sorted(chosen, key=lambda i: self.unit_index[i])
            self.row_of = {u: i for i, u in enumerate(self.unit_index)}
        else:
            self.order = list(chosen)
            self.row_of = None

    def pair(self, i):
        out = {}
        for f in self.fields:
            if f == "pair_key":
                out[f] = self.pair_key[i]
            elif f == "scene":
                out[f] = self.scene[i]
            elif f == "status":
                out[f] = self.status[i]
            elif f == "unit_index":
                out[f] = self.unit_index[i]
            elif f == "seed":
                out[f] = self.seed[i]
            elif f == "source_points":
                out[f] = self.source[self.source_off[i]:self.source_off[i + 1]].copy()
            elif f == "target_points":
                out[f] = self.target[self.target_off[i]:self.target_off[i + 1]].copy()
            elif f == "T_target_from_source":
                out[f] = self.transform[i].copy()
            elif f == "overlap_source":
                out[f] = float(self.overlap_source[i])
            elif f == "overlap_target":
                out[f] = float(self.overlap_target[i])
            elif f == "target_known_share":
                out[f] = self.known[self.known_off[i]:self.known_off[i + 1]].copy() if self.provenance else None
            elif f == "target_scene_share":
                out[f] = self.scene_share[self.scene_off[i]:self.scene_off[i + 1]].copy() if self.provenance else None
            elif f == "target_view":
                out[f] = self.view[self.view_off[i]:self.view_off[i + 1]].copy() if self.provenance else None
        for c, values in self.extra.items():
            out[c] = values[i]
        return out


class ShardCache:
    """The last ``size`` decoded shards of a dataset (least recently used first out)."""

    def __init__(self, size=1):
        self.size = max(1, int(size))
        self._items = OrderedDict()

    def get(self, key, load):
        if key in self._items:
            self._items.move_to_end(key)
            return self._items[key]
        value = load()
        self._items[key] = value
        while len(self._items) > self.size:
            self._items.popitem(last=False)
        return value
