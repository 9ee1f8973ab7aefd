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

    pairs = prd.PairDataset(ds)                                      # map-style: pairs[i], one row group read

Only committed shards (named by ``<dataset>/manifest/``) are read. See python/README.md.
"""

from .dataset import (
    INDEX_COLUMNS, PAIR_FIELDS, STATUSES, Dataset, DatasetError, Shard, open_dataset, points_array,
    selection_expression, unsigned_seed,
)
from .store import StoreError, filesystem_for
__version__ = "0.1.0"

__all__ = [
    "open_dataset", "Dataset", "Shard", "PairDataset", "StreamingPairDataset", "ShardShuffleSampler", "collate", "selection_expression",
    "unsigned_seed", "points_array", "filesystem_for", "DatasetError", "StoreError", "INDEX_COLUMNS",
    "PAIR_FIELDS", "STATUSES", "__version__",
]


def __getattr__(name):
    # The training module imports torch (when installed) to subclass torch.utils.data.Dataset: load it on
    # first use, so that reading a dataset does not pay for importing torch.
    if name in ("PairDataset", "StreamingPairDataset", "ShardShuffleSampler", "collate"):
        from . import training

        return getattr(training, name)
    raise AttributeError(f"module 'pointreggpt_data' has no attribute {name!r}")
