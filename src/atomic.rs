//! Atomic file publication: write a temporary file, fsync it, rename (or link) it into place, fsync the folder.
//! The shards' commit protocol and the checkpoints both write through it, so a crash never leaves a torn file.
//!
//! Temporary files live in one folder (a dataset's `.tmp/`, a checkpoint's own folder: on the same file
//! system as the targets) and
//! are named `<host>~<pid>~<target>~<nonce>.tmp`, so that [`TempName::parse`] can tell which process on
//! which host made them and whether that process still runs.

use crate::error::{Error, Result};
use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::{SystemTime, UNIX_EPOCH};

/// How [`write_atomic`] treats an existing target.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Publish {
    /// Replace it (rename).
    Replace,
    /// Keep it and report [`Published::AlreadyThere`] (hard link, which never replaces).
    KeepExisting,
}

/// What [`write_atomic`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Published {
    /// The target now holds the new bytes.
    Written,
    /// The target existed and was kept ([`Publish::KeepExisting`] only).
    AlreadyThere,
}

/// This machine's host name (from `/proc/sys/kernel/hostname`, `/etc/hostname` or `$HOSTNAME`), made safe
/// for file names.
pub fn hostname() -> &'static str {
    static HOST: OnceLock<String> = OnceLock::new();
    HOST.get_or_init(|| {
        let raw = ["/proc/sys/kernel/hostname", "/etc/hostname"]
            .iter()
            .find_map(|p| fs::read_to_string(p).ok().map(|s| s.trim().to_string()).filter(|s| !s.is_empty()))
            .or_else(|| std::env::var("HOSTNAME").ok().filter(|s| !s.is_empty()))
            .unwrap_or_else(|| "unknown-host".into());
        raw.chars().map(|c| if c.is_ascii_alphanumeric() || c == '.' || c == '-' { c } else { '-' }).collect()
    })
}

/// The parts of a temporary file name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TempName {
    pub host: String,
    pub pid: u32,
    /// File name of the target (`pairs-000012.parquet`).
    pub target: String,
    pub nonce: String,
}

impl TempName {
    /// A fresh name for a temporary file of `target`, owned by this process.
    pub fn new(target: &str) -> TempName {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let t = SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
        TempName {
            host: hostname().to_string(),
            pid: std::process::id(),
            target: target.to_string(),
            nonce: format!("{:x}{n:x}", t & 0xffff_ffff_ffff),
        }
    }

    /// The file name (`<host>~<pid>~<target>~<nonce>.tmp`).
    pub fn file_name(&self) -> String {
        format!("{}~{}~{}~{}.tmp", self.host, self.pid, self.target, self.nonce)
    }

    /// Parses a file name made by [`TempName::file_name`].
    pub fn parse(file_name: &str) -> Option<TempName> {
        let parts: Vec<&str> = file_name.strip_suffix(".tmp")?.split('~').collect();
        let [host, pid, target, nonce] = parts[..] else { return None };
        Some(TempName { host: host.into(), pid: pid.parse().ok()?, target: target.into(), nonce: nonce.into() })
    }

    /// Made on this host by a process that no longer runs (so nobody will finish it). Names from other
    /// hosts are never stale from here: their owners cannot be checked. Assumes host names are unique
    /// among the machines sharing the folder.
    pub fn is_stale(&self) -> bool {
        self.host == hostname() && self.pid != std::process::id() && !Path::new(&format!("/proc/{}", self.pid)).exists()
    }
}

/// Writes `bytes` to `target` atomically: readers see either no file (or the old one) or all of the new
/// bytes, also after a crash. The temporary file goes in `tmp_dir` (same file system as `target`).
pub fn write_atomic(tmp_dir: &Path, target: &Path, bytes: &[u8], mode: Publish) -> Result<Published> {
    let name = target
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| Error::InvalidArgument(format!("{}: target has no file name", target.display())))?;
    let tmp = tmp_dir.join(TempName::new(name).file_name());
    let result = write_synced(&tmp, bytes).and_then(|()| publish(&tmp, target, mode));
    if tmp.exists() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Creates `path` (which must not exist), writes `bytes` and fsyncs it.
fn write_synced(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut file = OpenOptions::new().write(true).create_new(true).open(path).map_err(|e| Error::io(path, e))?;
    file.write_all(bytes).map_err(|e| Error::io(path, e))?;
    file.sync_all().map_err(|e| Error::io(path, e))
}

/// Moves the finished temporary file `tmp` to `target`, then fsyncs the target's folder.
fn publish(tmp: &Path, target: &Path, mode: Publish) -> Result<Published> {
    let outcome = match mode {
        Publish::Replace => {
            fs::rename(tmp, target).map_err(|e| Error::io(target, e))?;
            Published::Written
        }
        Publish::KeepExisting => match fs::hard_link(tmp, target) {
            Ok(()) => Published::Written,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Published::AlreadyThere,
            // File systems without hard links: check then rename (a narrow race, only there).
            Err(_) if target.exists() => Published::AlreadyThere,
            Err(_) => {
                fs::rename(tmp, target).map_err(|e| Error::io(target, e))?;
                Published::Written
            }
        },
    };
    if outcome == Published::Written {
        sync_dir(target.parent().unwrap_or(Path::new(".")))?;
    }
    Ok(outcome)
}

/// fsyncs a folder, so that a rename in it survives a crash.
pub fn sync_dir(dir: &Path) -> Result<()> {
    File::open(dir).and_then(|d| d.sync_all()).map_err(|e| Error::io(dir, e))
}

/// The temporary files in `tmp_dir` (names that do not parse are listed with `None`).
pub fn list_temps(tmp_dir: &Path) -> Result<Vec<(PathBuf, Option<TempName>)>> {
    let mut out = Vec::new();
    let entries = match fs::read_dir(tmp_dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(out),
        Err(e) => return Err(Error::io(tmp_dir, e)),
    };
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(tmp_dir, e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        out.push((entry.path(), TempName::parse(&name)));
    }
    out.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_names_round_trip_and_are_unique() {
        let a = TempName::new("pairs-000003.parquet");
        let b = TempName::new("pairs-000003.parquet");
        assert_ne!(a.file_name(), b.file_name());
        assert_eq!(TempName::parse(&a.file_name()), Some(a.clone()));
        assert_eq!(a.pid, std::process::id());
        assert!(!a.host.contains('~') && !a.host.is_empty());
        assert_eq!(TempName::parse("pairs-000003.parquet"), None);
        assert_eq!(TempName::parse("h~notapid~x~1.tmp"), None);
    }

    #[test]
    fn staleness_follows_the_owner_process() {
        let mine = TempName::new("x");
        assert!(!mine.is_stale(), "this process runs");
        // A pid above the kernel's maximum never runs.
        let dead = TempName { pid: 4_194_304 + 17, ..mine.clone() };
        assert!(dead.is_stale());
        // A live process of this host (pid 1 always runs) keeps its temps.
        assert!(!TempName { pid: 1, ..mine.clone() }.is_stale());
        // Another host's temps are never stale from here.
        assert!(!TempName { host: "elsewhere".into(), ..dead }.is_stale());
    }

    #[test]
    fn replace_and_keep_existing() {
        let dir = tempfile::tempdir().unwrap();
        let tmp = dir.path().join(".tmp");
        fs::create_dir(&tmp).unwrap();
        let target = dir.path().join("f.txt");
        assert_eq!(write_atomic(&tmp, &target, b"one", Publish::KeepExisting).unwrap(), Published::Written);
        assert_eq!(write_atomic(&tmp, &target, b"two", Publish::KeepExisting).unwrap(), Published::AlreadyThere);
        assert_eq!(fs::read(&target).unwrap(), b"one");
        assert_eq!(write_atomic(&tmp, &target, b"three", Publish::Replace).unwrap(), Published::Written);
        assert_eq!(fs::read(&target).unwrap(), b"three");
        assert!(list_temps(&tmp).unwrap().is_empty(), "no temporary file is left behind");
    }

    #[test]
    fn failed_publication_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let tmp = dir.path().join(".tmp");
        fs::create_dir(&tmp).unwrap();
        let target = dir.path().join("missing-folder").join("f.txt");
        let err = write_atomic(&tmp, &target, b"x", Publish::Replace).unwrap_err();
        assert!(err.to_string().contains("missing-folder"), "{err}");
        assert!(list_temps(&tmp).unwrap().is_empty());
    }
}
