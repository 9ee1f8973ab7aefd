//! What publishing the Delta Lake table costs (`pointreggpt::shards::delta::publish`), in a folder and on a
//! local S3 server (moto, as in tests/store.rs): the cost per shard of one publisher (a first publish of
//! many shards, a catch-up of a few, a publish that finds the table current), and commit contention with
//! N = 1, 2, 4, 8 publishers at once, in the two shapes a build can take: N workers finishing at the same
//! moment, and N workers publishing after every shard (the worst case; the build publishes once per
//! worker). Shards are one tiny row each, so the times are the protocol's (listings, reads, create-only
//! writes), not Parquet's. Run: `cargo bench --bench delta`.

#[path = "../tests/support/mod.rs"]
#[allow(dead_code)]
mod support;

use support::store;

use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::delta::{publish, LOG_DIR};
use pointreggpt::shards::PairRow;
use std::sync::Barrier;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// A fresh dataset at `at` with shards `shards` committed, one row each.
fn dataset(at: &str, shards: std::ops::Range<u64>) -> Dataset {
    let ds = Dataset::create_or_open(at, "seed = 1\n", "bench").unwrap();
    for s in shards {
        ds.commit_pairs(s, s, 1, &[PairRow { unit_index: s, pair_key: format!("k#{s}"), config_hash: "bench".into(), ..Default::default() }]).unwrap();
    }
    ds
}

fn versions(ds: &Dataset) -> usize {
    ds.store().list(LOG_DIR).unwrap().len()
}

/// One publisher: first publish of `first` shards, catch-up of 8 more, and a publish of a current table.
fn one_publisher(name: &str, at: &str, first: u64) {
    let ds = dataset(at, 0..first);
    let t = Instant::now();
    let r = publish(&ds).unwrap();
    let first_ms = ms(t);
    assert_eq!((r.version, r.added), (0, first as usize));
    let mut catch_up = Vec::new();
    for round in 0..3u64 {
        let base = first + round * 8;
        for s in base..base + 8 {
            ds.commit_pairs(s, s, 1, &[PairRow { unit_index: s, pair_key: format!("k#{s}"), config_hash: "bench".into(), ..Default::default() }]).unwrap();
        }
        let t = Instant::now();
        assert_eq!(publish(&ds).unwrap().added, 8);
        catch_up.push(ms(t));
    }
    let noop = median((0..5).map(|_| {
        let t = Instant::now();
        assert!(!publish(&ds).unwrap().committed);
        ms(t)
    }).collect());
    let c = median(catch_up);
    println!(
        "{name:<10} {first:>7} {first_ms:>12.1} {:>12.2} {c:>14.1} {:>12.2} {noop:>14.1}",
        first_ms / first as f64,
        c / 8.0
    );
}

/// N publishers finishing at once over `shards` committed shards; returns (wall ms, versions, lost races).
fn finish_at_once(at: &str, n: usize, shards: u64) -> (f64, usize, u32) {
    let ds = dataset(at, 0..shards);
    let barrier = Barrier::new(n);
    let t = Instant::now();
    let lost: u32 = std::thread::scope(|s| {
        let hs: Vec<_> = (0..n).map(|_| s.spawn(|| {
            barrier.wait();
            publish(&ds).unwrap().conflicts
        })).collect();
        hs.into_iter().map(|h| h.join().unwrap()).sum()
    });
    (ms(t), versions(&ds), lost)
}

/// N publishers each committing `per` shards and publishing after each; returns (wall ms, versions,
/// lost races, median and max publish ms).
fn publish_per_shard(at: &str, n: u64, per: u64) -> (f64, usize, u32, f64, f64) {
    let ds = dataset(at, 0..0);
    let barrier = Barrier::new(n as usize);
    let t = Instant::now();
    let results: Vec<(u32, Vec<f64>)> = std::thread::scope(|s| {
        let hs: Vec<_> = (0..n)
            .map(|i| {
                let (ds, barrier) = (ds.clone(), &barrier);
                s.spawn(move || {
                    barrier.wait();
                    let (mut lost, mut times) = (0, Vec::new());
                    for j in 0..per {
                        let k = j * n + i;
                        ds.commit_pairs(k, k, 1, &[PairRow { unit_index: k, pair_key: format!("k#{k}"), config_hash: "bench".into(), ..Default::default() }]).unwrap();
                        let t = Instant::now();
                        lost += publish(&ds).unwrap().conflicts;
                        times.push(ms(t));
                    }
                    (lost, times)
                })
            })
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let wall = ms(t);
    let lost = results.iter().map(|r| r.0).sum();
    let all: Vec<f64> = results.into_iter().flat_map(|r| r.1).collect();
    let max = all.iter().copied().fold(0.0, f64::max);
    (wall, versions(&ds), lost, median(all), max)
}

fn main() {
    let moto = store::Moto::start();
    moto.set_env();
    moto.create_bucket("bench");
    let dir = tempfile::tempdir().unwrap();
    let folder = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let bucket = |name: &str| format!("s3://bench/{name}");
    println!("Machine: {} cores; shards of one tiny row; S3 = moto on 127.0.0.1 (every request a local HTTP round trip)", std::thread::available_parallelism().map_or(0, |n| n.get()));
    println!();
    println!("one publisher: first publish of all shards (version 0), catch-up of 8 new shards (median of 3), current table (median of 5)");
    println!("{:<10} {:>7} {:>12} {:>12} {:>14} {:>12} {:>14}", "where", "shards", "first ms", "ms/shard", "catch-up ms", "ms/shard", "no-op ms");
    for first in [64, 512] {
        one_publisher("folder", &folder(&format!("one-{first}")), first);
        one_publisher("s3 (moto)", &bucket(&format!("one-{first}")), first);
    }

    println!();
    println!("N workers finishing at once (64 committed shards, all N publish at the same moment)");
    println!("{:<10} {:>3} {:>10} {:>10} {:>12}", "where", "N", "wall ms", "versions", "lost races");
    for n in [1, 2, 4, 8] {
        for (name, at) in [("folder", folder(&format!("once-{n}"))), ("s3 (moto)", bucket(&format!("once-{n}")))] {
            let (wall, v, lost) = finish_at_once(&at, n, 64);
            println!("{name:<10} {n:>3} {wall:>10.1} {v:>10} {lost:>12}");
        }
    }

    println!();
    println!("N workers publishing after every shard (32 shards in all, 32/N each; the build itself publishes once per worker)");
    println!("{:<10} {:>3} {:>10} {:>10} {:>10} {:>14} {:>14} {:>14}", "where", "N", "wall ms", "shards/s", "versions", "lost/publish", "median pub ms", "max pub ms");
    for n in [1u64, 2, 4, 8] {
        for (name, at) in [("folder", folder(&format!("each-{n}"))), ("s3 (moto)", bucket(&format!("each-{n}")))] {
            let (wall, v, lost, med, max) = publish_per_shard(&at, n, 32 / n);
            println!(
                "{name:<10} {n:>3} {wall:>10.1} {:>10.1} {v:>10} {:>14.2} {med:>14.1} {max:>14.1}",
                32.0 / (wall / 1e3),
                lost as f64 / 32.0
            );
        }
    }
    println!("(a lost race costs one re-read of the new log versions and of the manifest, then a pause of 0-8·2^k ms)");
}
