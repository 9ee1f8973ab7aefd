//! The repair scenario both object stores share (tests/store.rs on moto, tests/azure.rs on Azurite).
//! Beside a committed dataset, writers of every kind leave upload records (`.tmp/`) and objects
//! (`shards/`): a live writer of this host (one upload unfinished, one object put but not committed),
//! a writer of another host, a writer of this host that died, and an orphan no record names.
//! `verify` must name each for what it is; `verify --repair` must remove exactly the dead writer's
//! record and object and the orphan, and leave the live and remote writers and the committed data alone.
//! How the records and objects are planted is the store's own (its Python peer); the names, and what
//! must happen to them, are here.

use std::collections::BTreeMap;
use std::process::Child;

/// A process that runs for as long as the test does (`sleep`): the live writer whose pid records name.
pub struct Running(pub Child);

impl Running {
    pub fn start() -> Running {
        Running(super::command("sleep").arg("600").spawn().unwrap())
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The shard objects and their upload records, named as the product names them
/// (`host~pid~object~n.tmp`).
pub struct Planted {
    /// The live writer's unfinished upload (S3 multipart, Azure uncommitted blocks) and its record.
    pub live_upload: &'static str,
    pub live_upload_record: String,
    /// The live writer's whole object, put but not yet committed, and its record.
    pub live_put: &'static str,
    pub live_put_record: String,
    /// A writer of another host: its record is not stale from here (for an hour).
    pub remote: &'static str,
    pub remote_record: String,
    /// A writer of this host that died (a pid above Linux's pid_max, never running) after its put.
    pub dead: &'static str,
    pub dead_record: String,
    /// A whole valid shard object that no record and no entry names (a writer that lost a race and
    /// could not delete it).
    pub orphan: &'static str,
}

impl Planted {
    /// The names for a live writer of this host with process id `pid`.
    pub fn new(pid: u32) -> Planted {
        let host = pointreggpt::atomic::hostname();
        let record = |host: &str, pid: u32, object: &str, n: u32| format!("{host}~{pid}~{object}~{n}.tmp");
        let (live_upload, live_put) = ("pairs-000005-1111111111111111.parquet", "pairs-000006-2222222222222222.parquet");
        let (remote, dead) = ("pairs-000007-3333333333333333.parquet", "pairs-000001-4444444444444444.parquet");
        Planted {
            live_upload,
            live_upload_record: record(&host, pid, live_upload, 1),
            live_put,
            live_put_record: record(&host, pid, live_put, 2),
            remote,
            remote_record: record("elsewhere.example", pid, remote, 3),
            dead,
            dead_record: record(&host, 4_194_304 + 9, dead, 4),
            orphan: "pairs-000002-5555555555555555.parquet",
        }
    }

    /// Plants everything but the live writer's unfinished upload (the store's own kind of object):
    /// `put_record(record_name, object)` writes `.tmp/<record_name>` naming `object`, `copy(object)` puts
    /// a whole valid shard as `shards/<object>`.
    pub fn plant(&self, put_record: impl Fn(&str, &str), copy: impl Fn(&str)) {
        for (object, record_name) in [(self.live_put, &self.live_put_record), (self.remote, &self.remote_record), (self.dead, &self.dead_record)] {
            put_record(record_name, object);
            copy(object);
        }
        copy(self.orphan);
    }

    /// Asserts that `verify`'s report names each planted file for what it is.
    pub fn assert_listed(&self, report: &str) {
        let running = "temporary file of a running or remote process";
        for (name, says) in [
            (self.dead_record.as_str(), "stale temporary file"),
            (self.live_upload_record.as_str(), running),
            (self.live_put_record.as_str(), running),
            (self.remote_record.as_str(), running),
            (self.orphan, "uncommitted shard file"),
        ] {
            assert!(report.lines().any(|l| l.contains(name) && l.contains(says)), "verify does not list {name} as {says}:\n{report}");
        }
    }

    /// Asserts what `verify --repair` (its output: `repaired`) did to the dataset's objects, listed
    /// `before` and `after` it with their size and ETag: the live and remote writers' records and objects
    /// are there, the dead writer's and the orphan are gone, every object of `before` is unchanged.
    /// (Whether the live writer's unfinished upload survived is the store's own question.)
    pub fn assert_repaired(&self, before: &BTreeMap<String, (u64, String)>, after: &BTreeMap<String, (u64, String)>, repaired: &str) {
        let kept = [
            format!(".tmp/{}", self.live_upload_record),
            format!(".tmp/{}", self.live_put_record),
            format!("shards/{}", self.live_put),
            format!(".tmp/{}", self.remote_record),
            format!("shards/{}", self.remote),
        ];
        for key in kept {
            assert!(after.contains_key(&key), "repair removed {key} of a running writer:\n{repaired}");
        }
        for key in [format!(".tmp/{}", self.dead_record), format!("shards/{}", self.dead), format!("shards/{}", self.orphan)] {
            assert!(!after.contains_key(&key), "repair left {key}:\n{repaired}");
        }
        for (key, v) in before {
            assert_eq!(after.get(key), Some(v), "repair changed the committed object {key}");
        }
    }
}
