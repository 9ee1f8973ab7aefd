"""StreamingPairDataset's promises that the once-per-epoch checks (check_package.py, loader_check.py) leave
open, checked against the shard files read here with pyarrow (tests/suite/python_package.rs runs it):

- unshuffled, one consumer: the `ok` pairs in file order, row groups in order, rows in unit order;
- the order within each consumer: its pieces (``pieces_of``) in reading order, each piece's rows as in
  the file, then the shuffle buffer: every pair leaves within ``buffer_size`` places of where it arrived,
  most pairs move, and some move nearly that far (a buffer that never shuffles, or one that holds the
  whole epoch, fails);
- ranks × DataLoader workers (the worker simulated through ``get_worker_info``): each consumer yields
  exactly the pairs of its pieces, whole pieces dealt round-robin (piece counts within one of each other);
- ``torch.distributed``'s rank and world size are the defaults: two processes in a gloo group, neither
  naming its rank, stream disjoint halves that together are every pair, each what rank=r,
  world_size=2 streams.

Usage: streaming_check.py <plan.json> with {"dataset": <folder>, "scratch": <folder>}; prints a JSON report.
"""
import json
import os
import sys
import tempfile

import pyarrow.parquet as pq
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

import pointreggpt_data as prd


def file_rows(ds):
    """{(shard position, row group): [(unit_index, pair_key, status), ...]} read from the files."""
    out = {}
    for k, shard in enumerate(ds.shards):
        f = pq.ParquetFile(shard.path)
        for g in range(f.num_row_groups):
            t = f.read_row_group(g, columns=["unit_index", "pair_key", "status"])
            out[(k, g)] = list(zip(t.column("unit_index").to_pylist(), t.column("pair_key").to_pylist(), t.column("status").to_pylist()))
    return out


def ok_keys(rows):
    return [key for _, key, status in rows if status == "ok"]


def piece_keys(rows, piece):
    k, groups = piece
    return [key for g in groups for key in ok_keys(rows[(k, g)])]


def keys_of(stream):
    return [p["pair_key"] for p in stream]


class FakeWorker:
    def __init__(self, id, num_workers):
        self.id, self.num_workers = id, num_workers


def as_worker(worker, workers, fn):
    real = torch.utils.data.get_worker_info
    torch.utils.data.get_worker_info = lambda: FakeWorker(worker, workers)
    try:
        return fn()
    finally:
        torch.utils.data.get_worker_info = real


def distributed_rank(rank, world, path, init, out):
    dist.init_process_group("gloo", init_method=f"file://{init}", rank=rank, world_size=world)
    try:
        stream = prd.StreamingPairDataset(path, seed=9, buffer_size=4, fields=["pair_key"])
        stream.set_epoch(1)
        with open(os.path.join(out, f"rank-{rank}.json"), "w") as f:
            json.dump({"keys": keys_of(stream), "consumer": list(stream.consumer())}, f)
    finally:
        dist.destroy_process_group()


def main():
    plan = json.load(open(sys.argv[1]))
    path, scratch = plan["dataset"], plan["scratch"]
    ds = prd.open_dataset(path)
    rows = file_rows(ds)
    all_ok = [key for kg in sorted(rows) for key in ok_keys(rows[kg])]
    for group in rows.values():
        units = [u for u, _, _ in group]
        assert units == sorted(units), "the writer keeps unit order within a row group"
    report = {"ok": len(all_ok), "row_groups": len(rows)}

    # Unshuffled, one consumer: file order exactly.
    plain = keys_of(prd.StreamingPairDataset(path, shuffle=False, fields=["pair_key"]))
    assert plain == all_ok, f"unshuffled: not the file order ({len(plain)} pairs, {len(all_ok)} ok in the files)"

    # Shuffled, one consumer: the arrival order is the pieces' rows; the buffer bounds every displacement.
    size = 4
    stream = prd.StreamingPairDataset(path, seed=3, buffer_size=size, fields=["pair_key"])
    stream.set_epoch(2)
    arrival = [key for piece in stream.pieces_of(0, 1) for key in piece_keys(rows, piece)]
    out = keys_of(stream)
    assert sorted(out) == sorted(arrival) == sorted(all_ok), "one consumer streams every ok pair once"
    assert arrival != all_ok, "the pieces come in a shuffled order"
    where = {key: i for i, key in enumerate(out)}
    moves = [abs(where[key] - a) for a, key in enumerate(arrival)]
    assert max(moves) <= size, f"a pair left {max(moves)} places from where it arrived; the buffer holds {size}"
    assert sum(m > 0 for m in moves) >= len(moves) // 2, f"only {sum(m > 0 for m in moves)} of {len(moves)} pairs moved: the buffer does not shuffle"
    assert max(moves) >= size - 1, f"no pair moved more than {max(moves)} places with a buffer of {size}"
    report["buffer"] = {"size": size, "largest_displacement": max(moves), "moved": sum(m > 0 for m in moves)}

    # Ranks x workers: each consumer streams exactly its pieces' pairs; counts within a piece of each other.
    ranks, workers = 2, 3
    counts, pieces, seen = [], [], []
    for rank in range(ranks):
        for worker in range(workers):
            s = prd.StreamingPairDataset(path, seed=5, buffer_size=8, rank=rank, world_size=ranks, fields=["pair_key"])
            s.set_epoch(1)
            consumer, consumers = as_worker(worker, workers, s.consumer)
            assert (consumer, consumers) == (rank * workers + worker, ranks * workers), (consumer, consumers)
            got = as_worker(worker, workers, lambda: keys_of(s))
            want = [key for piece in s.pieces_of(consumer, consumers) for key in piece_keys(rows, piece)]
            assert sorted(got) == sorted(want), f"consumer {consumer}: not the pairs of its pieces"
            counts.append(len(got))
            pieces.append(len(s.pieces_of(consumer, consumers)))
            seen += got
    assert sorted(seen) == sorted(all_ok), "ranks x workers: every ok pair exactly once"
    # Whole pieces dealt round-robin: the consumers' piece counts differ by at most one. (Their pair counts
    # can differ by more than a piece: a consumer of two full pieces against one of a shard's short last one.)
    assert max(pieces) - min(pieces) <= 1 and sum(pieces) == len(s.pieces), f"pieces per consumer {pieces} of {len(s.pieces)}"
    assert min(counts) > 0, f"a consumer streamed nothing: {counts}"
    report["per_consumer"] = counts
    report["pieces_per_consumer"] = pieces

    # torch.distributed's rank and world size are the defaults.
    out_dir = tempfile.mkdtemp(dir=scratch)
    init = os.path.join(out_dir, "init")
    mp.start_processes(distributed_rank, args=(2, path, init, out_dir), nprocs=2, join=True, start_method="spawn")
    streamed = [json.load(open(os.path.join(out_dir, f"rank-{r}.json"))) for r in range(2)]
    for r, got in enumerate(streamed):
        assert got["consumer"] == [r, 2], f"rank {r}: consumer {got['consumer']} without naming its rank"
        explicit = prd.StreamingPairDataset(path, seed=9, buffer_size=4, rank=r, world_size=2, fields=["pair_key"])
        explicit.set_epoch(1)
        assert got["keys"] == keys_of(explicit), f"rank {r}: not what rank={r}, world_size=2 streams"
    both = streamed[0]["keys"] + streamed[1]["keys"]
    assert sorted(both) == sorted(all_ok) and not set(streamed[0]["keys"]) & set(streamed[1]["keys"]), "the two ranks: every pair once"
    report["distributed"] = [len(s["keys"]) for s in streamed]
    print(json.dumps(report))


if __name__ == "__main__":
    main()
