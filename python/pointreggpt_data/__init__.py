"""Read pointreggpt pair datasets for training (pure Python: pyarrow and numpy; torch optional).

    import pointreggpt_data as prd
    ds = prd.open_dataset("s3://bucket/prgpt", storage_options={"endpoint_url": "http://127.0.0.1:9000"})
    for pair in ds.pairs(status="ok", overlap_source=(0.3, None), scene="7-scenes-redkitchen"):
        pair["source_points"], pair["target_points"], pair["T_target_from_source"]

    train = prd.StreamingPairDataset(ds, tensors=True, seed=0)       # a torch.utils.data.IterableDataset
    loader = torch.utils.data.DataLoader(train, batch_size=4, collate_fn=prd.collate, num_workers=2)
    for epoch in range(10):
        train.set_epoch(epoch)                                       # another shuffle each epoch
        for batch in loader: ...

    pairs = prd.PairDataset(ds, tensors=True)                        # map-style: pairs[i], one row group read
    sampler = prd.GroupShuffleSampler(pairs, batch_size=8, num_workers=2)  # random, each group decoded once
    loader = torch.utils.data.DataLoader(pairs, batch_size=8, sampler=sampler, collate_fn=prd.collate, num_workers=2)

    prd.show_pair(ds, "frame-000000#0")                              # the viewer extra: rerun, or an .rrd file

Only committed shards (named by ``<dataset>/manifest/``) are read. See python/README.md.
"""

from .dataset import (
    INDEX_COLUMNS, MINIMAL_FIELDS, PAIR_FIELDS, STATUSES, Dataset, DatasetError, Shard, open_dataset, points_array,
    selection_expression, unsigned_seed,
)
from .store import StoreError, filesystem_for
__version__ = "0.1.0"

__all__ = [
    "open_dataset", "Dataset", "Shard", "PairDataset", "StreamingPairDataset", "GroupShuffleSampler", "ShardShuffleSampler",
    "bounded_shuffle", "collate", "show_pair", "selection_expression", "MINIMAL_FIELDS",
    "unsigned_seed", "points_array", "filesystem_for", "DatasetError", "StoreError", "INDEX_COLUMNS",
    "PAIR_FIELDS", "STATUSES", "__version__",
]


def __getattr__(name):
    # The training module imports torch (when installed) to subclass torch.utils.data.Dataset: load it on
    # first use, so that reading a dataset does not pay for importing torch.
    if name in ("PairDataset", "StreamingPairDataset", "GroupShuffleSampler", "ShardShuffleSampler", "bounded_shuffle", "collate"):
        from . import training

        return getattr(training, name)
    if name == "show_pair":  # the viewer extra (rerun-sdk): imported only when asked for
        from . import viewer

        return viewer.show_pair
    raise AttributeError(f"module 'pointreggpt_data' has no attribute {name!r}")
