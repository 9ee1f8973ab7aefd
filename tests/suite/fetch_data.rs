//! scripts/fetch-realdata.py, the fetcher `make test` runs for the real frames when there is no local
//! copy, against a real HTTP server on 127.0.0.1 that this test starts (`POINTREGGPT_DATA_MIRROR` points
//! the fetcher at it). A small synthetic set with its own manifest checks the failure cases: a corrupted
//! file, a missing one (404), a connection dropped mid-file, a file damaged in the cache; each must be an
//! error naming the file and its URL, leave nothing unverified in place, and a rerun must finish the job
//! without fetching again what was verified. Then the real manifest: scripts/data-sources/manifest.txt must
//! match `POINTREGGPT_REAL_DATA` file for file, and a fetch from a mirror of it must give every file of
//! the five folders byte for byte (the derived ones made by the fetcher).

use std::collections::{BTreeMap, HashMap};
use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::{Arc, Mutex};
use crate::support::{python_command, real_data};

const FETCH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/fetch-realdata.py");
const MAINTAIN: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/realdata-manifest.py");

/// What the server does wrong for one path.
#[derive(Clone, Copy, Debug)]
enum Fault {
    /// 200 with the right length, one byte changed.
    Corrupt,
    /// 404.
    Missing,
    /// The full Content-Length announced, half the body sent, then the connection closed.
    Drop,
}

/// A static file server on 127.0.0.1 (a thread per connection, `Connection: close`) over a folder laid
/// out as the upstream servers are, with faults per path and a log of every path asked for.
struct Mirror {
    url: String,
    faults: Arc<Mutex<HashMap<String, Fault>>>,
    hits: Arc<Mutex<Vec<String>>>,
}

impl Mirror {
    fn start(root: &Path) -> Mirror {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let url = format!("http://{}", listener.local_addr().unwrap());
        let faults: Arc<Mutex<HashMap<String, Fault>>> = Arc::default();
        let hits: Arc<Mutex<Vec<String>>> = Arc::default();
        let (root, f, h) = (root.to_path_buf(), faults.clone(), hits.clone());
        std::thread::spawn(move || {
            for stream in listener.incoming().flatten() {
                let (root, f, h) = (root.clone(), f.clone(), h.clone());
                std::thread::spawn(move || serve(stream, &root, &f, &h));
            }
        });
        Mirror { url, faults, hits }
    }

    fn fault(&self, path: &str, fault: Option<Fault>) {
        let mut faults = self.faults.lock().unwrap();
        match fault {
            Some(f) => faults.insert(path.to_string(), f),
            None => faults.remove(path),
        };
    }

    /// How many times each path was asked for so far.
    fn hits(&self) -> BTreeMap<String, usize> {
        let mut counts = BTreeMap::new();
        for p in self.hits.lock().unwrap().iter() {
            *counts.entry(p.clone()).or_insert(0) += 1;
        }
        counts
    }
}

fn serve(mut stream: TcpStream, root: &Path, faults: &Mutex<HashMap<String, Fault>>, hits: &Mutex<Vec<String>>) {
    let mut reader = BufReader::new(stream.try_clone().unwrap());
    let mut request = String::new();
    if reader.read_line(&mut request).is_err() {
        return;
    }
    loop {
        let mut header = String::new();
        if reader.read_line(&mut header).map(|n| n == 0).unwrap_or(true) || header == "\r\n" {
            break;
        }
    }
    let path = request.split_whitespace().nth(1).unwrap_or("/").to_string();
    hits.lock().unwrap().push(path.clone());
    let fault = faults.lock().unwrap().get(&path).copied();
    let body = std::fs::read(root.join(path.trim_start_matches('/'))).ok();
    let (status, mut body) = match (fault, body) {
        (Some(Fault::Missing), _) | (_, None) => ("404 Not Found", b"not found".to_vec()),
        (_, Some(b)) => ("200 OK", b),
    };
    let length = body.len();
    match fault {
        Some(Fault::Corrupt) => {
            let mid = body.len() / 2;
            body[mid] ^= 0x5a;
        }
        Some(Fault::Drop) => body.truncate(length / 2),
        _ => {}
    }
    let head = format!("HTTP/1.1 {status}\r\nContent-Length: {length}\r\nConnection: close\r\n\r\n");
    let _ = stream.write_all(head.as_bytes()).and_then(|_| stream.write_all(&body));
    let _ = stream.flush();
    let _ = stream.shutdown(std::net::Shutdown::Both);
}

/// Runs the fetcher on `manifest` into `dest` through the mirror.
fn fetch(manifest: &Path, dest: &Path, mirror: &Mirror, only: &[&str]) -> Output {
    let mut c = python_command();
    c.arg(FETCH).arg("--manifest").arg(manifest).arg("--dest").arg(dest).env("POINTREGGPT_DATA_MIRROR", &mirror.url);
    for folder in only {
        c.args(["--only", folder]);
    }
    c.output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn sha256(path: &Path) -> String {
    let o = python_command()
        .args(["-c", "import hashlib, sys; print(hashlib.sha256(open(sys.argv[1], 'rb').read()).hexdigest())"])
        .arg(path)
        .output()
        .unwrap();
    assert!(o.status.success(), "python: {}", stderr(&o));
    String::from_utf8(o.stdout).unwrap().trim().to_string()
}

/// Every file under `dir` (relative path -> bytes), the fetcher's `.fetch` state left out.
fn tree(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(base: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.file_name().unwrap() == ".fetch" {
                continue;
            }
            if p.is_dir() {
                walk(base, &p, out);
            } else {
                out.insert(p.strip_prefix(base).unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// Files left in the fetcher's temporary folder (a half-written download would be one).
fn leftovers(dest: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dest.join(".fetch/tmp")).map(|d| d.flatten().map(|e| e.path()).collect()).unwrap_or_default()
}

const COMMIT: &str = "0123456789abcdef0123456789abcdef01234567";
const CAMERA: &str = "5.0e+02 0.0e+00 3.2e+02\n0.0e+00 5.0e+02 2.4e+02\n0.0e+00 0.0e+00 1.0e+00\n";
const INTRINSIC_4X4: &str =
    "500.000000 0.000000 320.000000 0.000000\n0.000000 500.000000 240.000000 0.000000\n0.000000 0.000000 1.000000 0.000000\n0.000000 0.000000 0.000000 1.000000\n";

/// A synthetic set: `scene/` with a text file, a 300 kB binary, a 3x3 camera matrix and the 4x4 file
/// derived from it, served from `<tmp>/mirror/owner/repo/<commit>/data/`. Returns (tmp, manifest, mirror).
fn synthetic() -> (tempfile::TempDir, PathBuf, Mirror) {
    let tmp = tempfile::tempdir().unwrap();
    let up = tmp.path().join("mirror/owner/repo").join(COMMIT).join("data");
    std::fs::create_dir_all(&up).unwrap();
    let blob: Vec<u8> = (0..300_000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
    let files: [(&str, &[u8]); 3] = [("a.txt", b"first file\n"), ("b.bin", &blob), ("cam.txt", CAMERA.as_bytes())];
    let mut manifest = format!("# synthetic\nsource up https://upstream.invalid/owner/repo/{COMMIT}/\n");
    for (name, bytes) in files {
        std::fs::write(up.join(name), bytes).unwrap();
        let pins = format!("{} {}", bytes.len(), sha256(&up.join(name)));
        manifest += &format!("file scene/{name} {pins} fetch up:data/{name}\n");
    }
    let derived = tmp.path().join("expected-intrinsic.txt");
    std::fs::write(&derived, INTRINSIC_4X4).unwrap();
    manifest += &format!(
        "file scene/intrinsic/intrinsic_depth.txt {} {} derive intrinsic-4x4 scene/cam.txt\n",
        INTRINSIC_4X4.len(),
        sha256(&derived)
    );
    let path = tmp.path().join("manifest.txt");
    std::fs::write(&path, manifest).unwrap();
    let mirror = Mirror::start(&tmp.path().join("mirror"));
    (tmp, path, mirror)
}

fn url_path(name: &str) -> String {
    format!("/owner/repo/{COMMIT}/data/{name}")
}

/// The folder as it must end up after a good fetch.
fn assert_complete(tmp: &Path, dest: &Path) {
    let up = tmp.join("mirror/owner/repo").join(COMMIT).join("data");
    let got = tree(dest);
    let want: BTreeMap<String, Vec<u8>> = [
        ("scene/a.txt".to_string(), std::fs::read(up.join("a.txt")).unwrap()),
        ("scene/b.bin".to_string(), std::fs::read(up.join("b.bin")).unwrap()),
        ("scene/cam.txt".to_string(), CAMERA.as_bytes().to_vec()),
        ("scene/intrinsic/intrinsic_depth.txt".to_string(), INTRINSIC_4X4.as_bytes().to_vec()),
    ]
    .into();
    assert!(got == want, "fetched files differ: got {:?}", got.keys().collect::<Vec<_>>());
    assert!(dest.join(".fetch/scene.complete").is_file(), "the folder is not marked complete");
    assert!(leftovers(dest).is_empty(), "temporary files left: {:?}", leftovers(dest));
}

#[test]
fn good_files_are_fetched_verified_and_derived_once() {
    let _timing = crate::support::timed();
    let (tmp, manifest, mirror) = synthetic();
    let dest = tmp.path().join("cache");
    let o = fetch(&manifest, &dest, &mirror, &[]);
    assert!(o.status.success(), "fetch failed: {}", stderr(&o));
    assert_complete(tmp.path(), &dest);
    let first = mirror.hits();
    assert_eq!(first.values().sum::<usize>(), 3, "one request a fetched file: {first:?}");
    // Once: a second run asks the server for nothing.
    let o = fetch(&manifest, &dest, &mirror, &[]);
    assert!(o.status.success(), "second fetch failed: {}", stderr(&o));
    assert_eq!(mirror.hits(), first, "a complete folder was fetched again");
}

/// A fetch from the synthetic mirror with `file` served wrong (`fault`): it must fail. Returns the setup
/// (temporary folder, manifest, destination, mirror) and the fetcher's stderr.
fn failing_fetch(file: &str, fault: Fault, what: &str) -> (tempfile::TempDir, PathBuf, PathBuf, Mirror, String) {
    let (tmp, manifest, mirror) = synthetic();
    let dest = tmp.path().join("cache");
    mirror.fault(&url_path(file), Some(fault));
    let o = fetch(&manifest, &dest, &mirror, &[]);
    let err = stderr(&o);
    assert!(!o.status.success(), "{what} was accepted: {err}");
    (tmp, manifest, dest, mirror, err)
}

/// The server serves `file` right again: the rerun completes and fetches only what was not verified.
fn rerun_after_the_server_is_fixed(tmp: &tempfile::TempDir, manifest: &Path, dest: &Path, mirror: &Mirror, file: &str) {
    mirror.fault(&url_path(file), None);
    let o = fetch(manifest, dest, mirror, &[]);
    assert!(o.status.success(), "rerun against a good server failed: {}", stderr(&o));
    assert_complete(tmp.path(), dest);
    let hits = mirror.hits();
    assert_eq!(hits[&url_path("a.txt")], 1, "a verified file was fetched again: {hits:?}");
}

#[test]
fn a_corrupted_file_is_an_error_naming_it_and_its_url_and_is_not_kept() {
    let _timing = crate::support::timed();
    let (tmp, manifest, dest, mirror, err) = failing_fetch("b.bin", Fault::Corrupt, "a file whose SHA-256 differs");
    assert!(err.contains("scene/b.bin") && err.contains("SHA-256"), "error does not name the file and the hash: {err}");
    assert!(err.contains(&format!("{}{}", mirror.url, url_path("b.bin"))), "error does not name the URL: {err}");
    assert!(err.contains(&format!("https://upstream.invalid{}", url_path("b.bin"))), "error does not name the source: {err}");
    assert!(!dest.join("scene/b.bin").exists(), "the corrupt bytes were left in place");
    assert!(!dest.join(".fetch/scene.complete").exists(), "a folder with a bad file was marked complete");
    assert!(!dest.join("scene/intrinsic/intrinsic_depth.txt").exists(), "derived from an incomplete folder");
    assert!(leftovers(&dest).is_empty(), "temporary files left: {:?}", leftovers(&dest));
    rerun_after_the_server_is_fixed(&tmp, &manifest, &dest, &mirror, "b.bin");
}

#[test]
fn a_missing_file_is_an_error_naming_it() {
    let _timing = crate::support::timed();
    let (_tmp, _manifest, dest, _mirror, err) = failing_fetch("cam.txt", Fault::Missing, "a 404");
    assert!(err.contains("scene/cam.txt") && err.contains("404"), "error does not name the file and the 404: {err}");
    assert!(err.contains(&url_path("cam.txt")), "error does not name the URL: {err}");
    assert!(!dest.join("scene/cam.txt").exists() && !dest.join("scene/intrinsic/intrinsic_depth.txt").exists());
    assert!(!dest.join(".fetch/scene.complete").exists(), "a folder with a missing file was marked complete");
}

#[test]
fn a_dropped_connection_leaves_nothing_half_written_and_a_rerun_completes() {
    let _timing = crate::support::timed();
    let (tmp, manifest, dest, mirror, err) = failing_fetch("b.bin", Fault::Drop, "a file cut short");
    assert!(err.contains("scene/b.bin") && err.contains(&url_path("b.bin")), "error does not name the file and URL: {err}");
    assert!(mirror.hits()[&url_path("b.bin")] >= 2, "a dropped connection is retried");
    assert!(!dest.join("scene/b.bin").exists(), "half a file was put in place");
    assert!(leftovers(&dest).is_empty(), "temporary files left: {:?}", leftovers(&dest));
    assert!(!dest.join(".fetch/scene.complete").exists());
    rerun_after_the_server_is_fixed(&tmp, &manifest, &dest, &mirror, "b.bin");
}

#[test]
fn a_file_damaged_in_the_cache_is_fetched_again() {
    let _timing = crate::support::timed();
    let (tmp, manifest, mirror) = synthetic();
    let dest = tmp.path().join("cache");
    assert!(fetch(&manifest, &dest, &mirror, &[]).status.success());
    // Cut short after the folder was complete: the size check catches it on the next run.
    let b = dest.join("scene/b.bin");
    let bytes = std::fs::read(&b).unwrap();
    std::fs::write(&b, &bytes[..1000]).unwrap();
    let o = fetch(&manifest, &dest, &mirror, &[]);
    assert!(o.status.success(), "refetch failed: {}", stderr(&o));
    assert_complete(tmp.path(), &dest);
    assert_eq!(mirror.hits()[&url_path("b.bin")], 2);
    assert_eq!(mirror.hits()[&url_path("a.txt")], 1);
}

/// The real manifest: up to date with the local copy, and a fetch from a mirror of it rebuilds all
/// five folders byte for byte, derived files included.
#[test]
fn the_real_manifest_rebuilds_the_local_folders_byte_for_byte() {
    let _timing = crate::support::timed();
    let Some(real) = real_data() else { return };
    let o = python_command().arg(MAINTAIN).arg("--check").arg("--data").arg(&real).output().unwrap();
    assert!(o.status.success(), "scripts/data-sources/manifest.txt does not match {}: {}", real.display(), stderr(&o));
    let tmp = tempfile::tempdir().unwrap();
    let o = python_command().arg(MAINTAIN).arg("--data").arg(&real).arg("--mirror").arg(tmp.path().join("mirror")).output().unwrap();
    assert!(o.status.success(), "mirror: {}", stderr(&o));
    let mirror = Mirror::start(&tmp.path().join("mirror"));
    let dest = tmp.path().join("cache");
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/data-sources/manifest.txt");
    let t0 = std::time::Instant::now();
    let o = fetch(&manifest, &dest, &mirror, &[]);
    assert!(o.status.success(), "fetch of the real manifest failed: {}", stderr(&o));
    let folders = ["7scenes-redkitchen", "apcbox-realsense", "icl-nuim-livingroom", "sun3d-studyroom-5frames", "tum-fr3-cabinet-keyframes"];
    let (got, mut want) = (tree(&dest), BTreeMap::new());
    for f in folders {
        for (k, v) in tree(&real.join(f)) {
            want.insert(format!("{f}/{k}"), v);
        }
    }
    assert_eq!(got.len(), want.len(), "file count differs");
    for (k, v) in &want {
        assert!(got.get(k) == Some(v), "{k} differs from {}", real.display());
    }
    eprintln!("fetched {} files of 5 folders from the local mirror in {:.1} s", got.len(), t0.elapsed().as_secs_f64());
}

/// Two folders, `a-first` and `b-second` (fetched in that order), of two files each, served from
/// `<tmp>/mirror/owner/repo/<commit>/data/<folder>/`. Returns (tmp, manifest, mirror).
fn two_folders() -> (tempfile::TempDir, PathBuf, Mirror) {
    let tmp = tempfile::tempdir().unwrap();
    let mut manifest = format!("# two folders\nsource up https://upstream.invalid/owner/repo/{COMMIT}/\n");
    for folder in ["a-first", "b-second"] {
        let up = tmp.path().join("mirror/owner/repo").join(COMMIT).join("data").join(folder);
        std::fs::create_dir_all(&up).unwrap();
        for (name, bytes) in [("x.txt", format!("{folder} x\n")), ("y.txt", format!("{folder} y\n").repeat(1000))] {
            std::fs::write(up.join(name), &bytes).unwrap();
            manifest += &format!("file {folder}/{name} {} {} fetch up:data/{folder}/{name}\n", bytes.len(), sha256(&up.join(name)));
        }
    }
    let path = tmp.path().join("manifest.txt");
    std::fs::write(&path, manifest).unwrap();
    let mirror = Mirror::start(&tmp.path().join("mirror"));
    (tmp, path, mirror)
}

/// A folder that fails does not stop the ones after it: they are fetched, verified and marked complete,
/// and the run still fails naming the failing file; the rerun fetches only what failed.
#[test]
fn a_failing_folder_does_not_stop_the_others() {
    let _timing = crate::support::timed();
    let (tmp, manifest, mirror) = two_folders();
    let dest = tmp.path().join("cache");
    let broken = format!("/owner/repo/{COMMIT}/data/a-first/y.txt");
    mirror.fault(&broken, Some(Fault::Missing));
    let o = fetch(&manifest, &dest, &mirror, &[]);
    let err = stderr(&o);
    assert!(!o.status.success() && err.contains("a-first/y.txt") && err.contains("404"), "{err}");
    assert!(!dest.join(".fetch/a-first.complete").exists(), "a folder with a missing file was marked complete");
    assert!(dest.join(".fetch/b-second.complete").is_file(), "the folder after a failing one was not fetched: {err}");
    assert_eq!(std::fs::read_to_string(dest.join("b-second/x.txt")).unwrap(), "b-second x\n");
    assert!(leftovers(&dest).is_empty(), "temporary files left: {:?}", leftovers(&dest));
    mirror.fault(&broken, None);
    let o = fetch(&manifest, &dest, &mirror, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let hits = mirror.hits();
    assert_eq!(hits[&format!("/owner/repo/{COMMIT}/data/b-second/x.txt")], 1, "a complete folder was fetched again: {hits:?}");
    assert_eq!(hits[&broken], 2, "{hits:?}");
    assert!(dest.join(".fetch/a-first.complete").is_file());
}

/// `--only` fetches the named folders and nothing else; a name the manifest lacks is an error listing
/// the folders it has.
#[test]
fn only_fetches_the_named_folders() {
    let _timing = crate::support::timed();
    let (tmp, manifest, mirror) = two_folders();
    let dest = tmp.path().join("cache");
    let o = fetch(&manifest, &dest, &mirror, &["b-second"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(dest.join(".fetch/b-second.complete").is_file() && !dest.join("a-first").exists(), "{:?}", tree(&dest).keys());
    assert!(mirror.hits().keys().all(|p| p.contains("/b-second/")), "{:?}", mirror.hits());
    let o = fetch(&manifest, &dest, &mirror, &["c-none"]);
    let err = stderr(&o);
    assert!(!o.status.success() && err.contains("no folder 'c-none'") && err.contains("a-first, b-second"), "{err}");
    let o = fetch(&manifest, &dest, &mirror, &["a-first", "b-second"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(tree(&dest).len(), 4);
    assert_eq!(mirror.hits().len(), 4, "each file asked for once: {:?}", mirror.hits());
}

/// Temporary files an interrupted run left more than an hour ago are removed at the start of a run;
/// recent ones (a run going on beside this one) stay.
#[test]
fn stale_temporary_files_are_removed_and_recent_ones_kept() {
    let _timing = crate::support::timed();
    let (tmp, manifest, mirror) = two_folders();
    let dest = tmp.path().join("cache");
    let tmp_dir = dest.join(".fetch/tmp");
    std::fs::create_dir_all(&tmp_dir).unwrap();
    let (old, recent) = (tmp_dir.join("old.part"), tmp_dir.join("recent.part"));
    std::fs::write(&old, b"half a file").unwrap();
    std::fs::write(&recent, b"being written").unwrap();
    let two_hours_ago = std::time::SystemTime::now() - std::time::Duration::from_secs(7200);
    std::fs::File::options().write(true).open(&old).unwrap().set_modified(two_hours_ago).unwrap();
    let o = fetch(&manifest, &dest, &mirror, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!old.exists(), "a temporary file two hours old was left");
    assert!(recent.exists(), "a recent temporary file (another run's) was removed");
    assert_eq!(leftovers(&dest), vec![recent]);
}

/// The manifest against its upstreams, not only against the script that wrote it: for one file of each
/// source, read from the upstream repository itself (tests/fixtures/upstream/, SOURCES.txt says from
/// where), the manifest must fetch that path of that repository and pin those bytes (size and SHA-256).
/// A wrong repository, a wrong path or a pin of other bytes fails. (The pinned commits cannot be checked
/// offline; the fetch from GitHub itself is what checks them.)
#[test]
fn the_manifest_fetches_files_from_the_repositories_and_paths_that_publish_them() {
    let _timing = crate::support::timed();
    let upstream = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/upstream");
    let manifest = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/data-sources/manifest.txt")).unwrap();
    let mut sources: HashMap<String, String> = HashMap::new();
    let mut pins: HashMap<String, (u64, String)> = HashMap::new();
    for line in manifest.lines().filter(|l| !l.starts_with('#')) {
        let f: Vec<&str> = line.split_whitespace().collect();
        match f.first() {
            Some(&"source") => drop(sources.insert(f[1].to_string(), f[2].to_string())),
            Some(&"file") if f[4] == "fetch" => drop(pins.insert(f[5].to_string(), (f[2].parse().unwrap(), f[3].to_string()))),
            _ => {}
        }
    }
    let listed = std::fs::read_to_string(upstream.join("SOURCES.txt")).unwrap();
    let mut checked = Vec::new();
    for line in listed.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty()) {
        let f: Vec<&str> = line.split_whitespace().collect();
        let (source, repo, path) = (f[0], f[1], f[3]);
        let prefix = sources.get(source).unwrap_or_else(|| panic!("the manifest has no source {source}"));
        assert!(prefix.starts_with(&format!("https://raw.githubusercontent.com/{repo}/")), "source {source} is {prefix}, not {repo}");
        let bytes = std::fs::read(upstream.join(source).join(path)).unwrap();
        let (size, sha) = pins.get(&format!("{source}:{path}")).unwrap_or_else(|| panic!("the manifest fetches no {source}:{path}"));
        assert_eq!(*size, bytes.len() as u64, "{source}:{path}: the manifest's size");
        assert_eq!(*sha, sha256(&upstream.join(source).join(path)), "{source}:{path}: the manifest pins other bytes than {repo} publishes");
        checked.push(source.to_string());
    }
    checked.sort();
    let mut all: Vec<String> = sources.keys().cloned().collect();
    all.sort();
    assert_eq!(checked, all, "one upstream file of each source");
}
