#!/usr/bin/env python3
# Fetches the real depth frames the tests read (the five folders of scripts/data-sources/manifest.txt) from
# their public sources into a cache folder, each file pinned by size and SHA-256; `make test` runs it when
# neither POINTREGGPT_REAL_DATA nor ../shared/realdata is there. Standard library only.
#
# Each file is downloaded to a temporary file beside the cache, checked (size, SHA-256), then renamed into
# place, so a file that is in place is whole and verified. A folder counts as complete only when every one
# of its files is; a stamp in <dest>/.fetch says so, and a rerun keeps every verified file and fetches only
# the rest. A few files are not on any server as they are here: they are made from fetched originals by a
# named derivation below (DERIVATIONS) and checked against the same pins, or copied from the checkout
# (the SOURCE.txt notes). Any file that is missing, cut short or different is an error naming the file and
# the URL it came from, and the exit status is 1.
#
# POINTREGGPT_DATA_MIRROR=<url> (or --mirror) fetches every URL from that server instead, same paths:
# https://raw.githubusercontent.com/<owner>/<repo>/<commit>/<path> becomes <mirror>/<owner>/<repo>/<commit>/<path>.
import argparse
import bisect
import concurrent.futures
import fnmatch
import hashlib
import http.client
import os
import re
import struct
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
import zlib
from array import array

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = os.path.join(ROOT, "scripts", "data-sources", "manifest.txt")
ATTEMPTS = 3  # per URL, for network errors and 5xx/429 answers; a wrong hash or a 404 is not retried
WORKERS = 8
LFS_POINTER = b"version https://git-lfs.github.com/spec/"


class FetchError(Exception):
    pass


# ---- the manifest ----------------------------------------------------------------------------------------


class Entry:
    """One file of the data folder: where it goes, its pins, and how to get it."""

    def __init__(self, path, size, sha256, how, args):
        self.path, self.size, self.sha256, self.how, self.args = path, size, sha256, how, args
        self.folder = path.split("/", 1)[0]


def read_manifest(path):
    """Returns (sources: name -> URL prefix, entries) of a manifest file (format: its header comment)."""
    sources, entries = {}, []
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            words = line.split()
            if not words or words[0].startswith("#"):
                continue
            if words[0] == "source" and len(words) == 3:
                sources[words[1]] = words[2]
            elif words[0] == "file" and len(words) >= 6 and words[4] in ("fetch", "derive", "copy"):
                entries.append(Entry(words[1], int(words[2]), words[3], words[4], words[5:]))
            else:
                raise FetchError(f"{path}:{n}: not a manifest line: {line.strip()}")
    for e in entries:
        if e.how == "fetch":
            source_url(sources, e.args[0], path)
    return sources, entries


def source_url(sources, ref, manifest="the manifest"):
    """`name:path` -> the public URL (the prefix of source `name` + path)."""
    name, _, rel = ref.partition(":")
    if name not in sources or not rel:
        raise FetchError(f"{manifest}: '{ref}' names no source line")
    return sources[name] + rel


def mirrored(url, mirror):
    """(the URL to download, how errors name it): `url` itself, or the same path on the mirror."""
    if not mirror:
        return url, url
    there = mirror.rstrip("/") + "/" + urllib.parse.urlsplit(url).path.lstrip("/")
    return there, f"{there}, mirror of {url}"


# ---- downloads -------------------------------------------------------------------------------------------


def download(url, label, what, dest_tmp_dir, size=None):
    """Downloads `url` (named `label` in errors) into a new temporary file in `dest_tmp_dir`; returns its
    path. The caller renames or removes it. Stops early when more than `size` bytes arrive."""
    last = None
    for attempt in range(ATTEMPTS):
        if attempt:
            time.sleep(0.5 * attempt)
        fd, tmp = tempfile.mkstemp(dir=dest_tmp_dir, suffix=".part")
        try:
            req = urllib.request.Request(url, headers={"User-Agent": "pointreggpt-fetch-realdata"})
            with os.fdopen(fd, "wb") as out, urllib.request.urlopen(req, timeout=60) as r:
                got = 0
                while True:
                    chunk = r.read(1 << 16)
                    if not chunk:
                        break
                    got += len(chunk)
                    if size is not None and got > size:
                        raise FetchError(f"{what}: more than the expected {size} bytes from {label}")
                    out.write(chunk)
                expected = r.headers.get("Content-Length")
                if expected is not None and got != int(expected):  # urllib returns b"" when the peer hangs up
                    raise ConnectionError(f"connection closed after {got} of {expected} bytes")
                out.flush()
                os.fsync(out.fileno())
            return tmp
        except urllib.error.HTTPError as e:
            os.unlink(tmp)
            last = f"{what}: HTTP {e.code} {e.reason} from {label}"
            if e.code != 429 and e.code < 500:
                raise FetchError(last) from None
        except FetchError:
            os.unlink(tmp)
            raise
        except (OSError, http.client.HTTPException, ValueError) as e:  # refused, reset, cut short, timed out
            os.unlink(tmp)
            last = f"{what}: download from {label} failed: {e!r}"
    raise FetchError(f"{last} (after {ATTEMPTS} attempts)")


def file_sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def check_pins(entry, data_or_path, origin):
    """Raises unless the bytes (or the file) have the entry's size and SHA-256."""
    if isinstance(data_or_path, (bytes, bytearray)):
        size, sha, head = len(data_or_path), hashlib.sha256(data_or_path).hexdigest(), bytes(data_or_path[:64])
    else:
        size, sha = os.path.getsize(data_or_path), file_sha256(data_or_path)
        with open(data_or_path, "rb") as f:
            head = f.read(64)
    if size == entry.size and sha == entry.sha256:
        return
    hint = " (a Git LFS pointer, not the file: the manifest should use the media URL)" if head.startswith(LFS_POINTER) else ""
    raise FetchError(
        f"{entry.path}: {size} bytes with SHA-256 {sha}, expected {entry.size} bytes with SHA-256 {entry.sha256} "
        f"(from {origin}){hint}"
    )


def put_in_place(tmp, final):
    os.chmod(tmp, 0o644)  # mkstemp makes it private; the data is not
    os.makedirs(os.path.dirname(final), exist_ok=True)
    os.replace(tmp, final)


def write_verified(entry, data, dest, tmp_dir, origin):
    """Checks `data` against the entry's pins, then writes it into place through a temporary file."""
    check_pins(entry, data, origin)
    fd, tmp = tempfile.mkstemp(dir=tmp_dir, suffix=".part")
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(data)
            out.flush()
            os.fsync(out.fileno())
        put_in_place(tmp, os.path.join(dest, entry.path))
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


# ---- derivations: files made from fetched originals ------------------------------------------------------


def rows_of_numbers(text, columns, what):
    """The non-comment rows of a whitespace-separated table, as lists of the original number strings."""
    rows = []
    for line in text.splitlines():
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) != columns or not all(re.fullmatch(r"[-+0-9.eE]+", w) for w in words):
            raise FetchError(f"{what}: expected {columns} numbers a row, got: {line.strip()}")
        rows.append(words)
    return rows


def intrinsic_4x4(inputs, folder):
    """ScanNet's intrinsic_depth.txt (4x4, '%f') from a 3x3 camera-intrinsics.txt."""
    (what, text), = inputs
    k = [[float(w) for w in row] for row in rows_of_numbers(text, 3, what)]
    if len(k) != 3:
        raise FetchError(f"{what}: expected a 3x3 matrix")
    m = [k[0] + [0.0], k[1] + [0.0], k[2] + [0.0], [0.0, 0.0, 0.0, 1.0]]
    return "".join(" ".join("%f" % v for v in row) + "\n" for row in m).encode()


def tum_poses(inputs):
    (what, text), = inputs
    return rows_of_numbers(text, 8, what)  # timestamp tx ty tz qx qy qz qw, as written upstream


def tum_groundtruth(inputs, folder):
    """TUM's groundtruth.txt from the key-frame pose list (timestamp tx ty tz qx qy qz qw), numbers as given."""
    head = "# ground truth trajectory (motion capture)\n# timestamp tx ty tz qx qy qz qw\n"
    return (head + "".join(" ".join(r) + "\n" for r in tum_poses(inputs))).encode()


def tum_depth_list(inputs, folder):
    """TUM's depth.txt: one depth/<timestamp>.png a key frame, timestamps from the pose list, same order."""
    head = "# depth maps (TUM fr3_cabinet key frames; timestamps from the ground-truth poses, same order)\n# timestamp filename\n"
    return (head + "".join(f"{r[0]} depth/{r[0]}.png\n" for r in tum_poses(inputs))).encode()


def png_gray16(path):
    """(width, height, values) of a non-interlaced 16-bit greyscale PNG."""
    with open(path, "rb") as f:
        data = f.read()
    pos, idat, header = 8, [], None
    while pos + 8 <= len(data):
        n, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + n]
        pos += 12 + n
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
    if header is None or header[2:4] != (16, 0) or header[6] != 0:
        raise FetchError(f"{path}: not a non-interlaced 16-bit greyscale PNG")
    w, h = header[0], header[1]
    raw, stride = zlib.decompress(b"".join(idat)), 2 * w
    prev, out = bytearray(stride), bytearray()
    for y in range(h):
        start = y * (stride + 1)
        kind, line = raw[start], bytearray(raw[start + 1 : start + 1 + stride])
        if kind == 2:  # Up
            line = bytearray((x + b) & 255 for x, b in zip(line, prev))
        elif kind in (1, 3, 4):  # Sub, Average, Paeth: two byte lanes (2-byte pixels), a = left, c = upper left
            for lane in (0, 1):
                a = c = 0
                for i in range(lane, stride, 2):
                    b = prev[i]
                    if kind == 1:
                        a = (line[i] + a) & 255
                    elif kind == 3:
                        a = (line[i] + ((a + b) >> 1)) & 255
                    else:
                        pa, pb = b - c, a - c
                        pc = abs(pa + pb)
                        pa, pb = abs(pa), abs(pb)
                        a = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
                    line[i] = a
                    c = b
        out += line
        prev = line
    values = array("H", bytes(out))
    if sys.byteorder == "little":
        values.byteswap()
    return w, h, values


def depth_stats_row(path):
    """One row of depth_stats.tsv: the raw range, the share of zeros and the median of the valid depths (m)."""
    w, h, v = png_gray16(path)
    ordered = sorted(v)
    valid = ordered[bisect.bisect_right(ordered, 0):]
    n = len(valid)
    median = (valid[n // 2] if n % 2 else (valid[n // 2 - 1] + valid[n // 2]) / 2) / 1000.0
    zero = (len(v) - n) / len(v)
    top = ordered[-1]
    return "\t".join([os.path.basename(path), "I;16", str(w), str(h), "uint16", str(valid[0]), str(top),
                      "%.4f" % zero, "%.3f" % median, "%.3f" % (valid[0] / 1000.0), "%.3f" % (top / 1000.0)])


def depth_stats(inputs, folder, pattern):
    """A folder's depth_stats.tsv: one row per depth PNG matching `pattern`, by name."""
    names = sorted(n for n in os.listdir(folder) if fnmatch.fnmatch(n, pattern))
    paths = [os.path.join(folder, n) for n in names]
    with concurrent.futures.ProcessPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        rows = list(pool.map(depth_stats_row, paths, chunksize=8))
    head = "file\tmode\twidth\theight\tdtype\traw_min_nonzero\traw_max\tzero_frac\tmedian_m\tmin_m\tmax_m\n"
    return (head + "".join(r + "\n" for r in rows)).encode()


# name -> function(inputs: [(what, text)], output folder, *literal args) -> bytes. An argument `source:path`
# is fetched (not pinned itself: the result is) and passed as input; `pattern=...` is passed literally; any
# other argument is a file of the data folder, fetched and verified before the derivation runs.
DERIVATIONS = {
    "intrinsic-4x4": intrinsic_4x4,
    "tum-groundtruth": tum_groundtruth,
    "tum-depth-list": tum_depth_list,
    "depth-stats": depth_stats,
}


# ---- one folder ------------------------------------------------------------------------------------------


def fetch_entry(entry, sources, dest, tmp_dir, mirror):
    final = os.path.join(dest, entry.path)
    if entry.how == "copy":
        src = os.path.join(ROOT, entry.args[0])
        with open(src, "rb") as f:
            write_verified(entry, f.read(), dest, tmp_dir, src)
        return
    url, label = mirrored(source_url(sources, entry.args[0]), mirror)
    tmp = download(url, label, entry.path, tmp_dir, entry.size)
    try:
        check_pins(entry, tmp, label)
        put_in_place(tmp, final)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def derive_entry(entry, sources, dest, tmp_dir, mirror):
    name, args = entry.args[0], entry.args[1:]
    if name not in DERIVATIONS:
        raise FetchError(f"{entry.path}: unknown derivation '{name}'")
    inputs, literal, origin = [], [], []
    for a in args:
        if a.startswith("pattern="):
            literal.append(a[len("pattern="):])
            origin.append(f"{a} in {entry.folder}")
        elif ":" in a:
            url, label = mirrored(source_url(sources, a), mirror)
            tmp = download(url, label, f"{entry.path} (input {a})", tmp_dir)
            try:
                with open(tmp, encoding="utf-8") as f:
                    inputs.append((label, f.read()))
            finally:
                os.unlink(tmp)
            origin.append(label)
        else:
            with open(os.path.join(dest, a), encoding="utf-8") as f:
                inputs.append((a, f.read()))
            origin.append(a)
    folder = os.path.dirname(os.path.join(dest, entry.path))
    data = DERIVATIONS[name](inputs, folder, *literal)
    write_verified(entry, data, dest, tmp_dir, f"derivation {name} of {', '.join(origin)}")


def folder_stamp(entries):
    lines = "".join(f"{e.path} {e.size} {e.sha256} {e.how} {' '.join(e.args)}\n" for e in entries)
    return hashlib.sha256(lines.encode()).hexdigest()


def fetch_folder(folder, entries, sources, dest, mirror, log):
    """Makes `dest/folder` complete; returns the number of files fetched or made."""
    state = os.path.join(dest, ".fetch")
    tmp_dir = os.path.join(state, "tmp")
    os.makedirs(tmp_dir, exist_ok=True)
    stamp_path = os.path.join(state, folder + ".complete")
    stamp = folder_stamp(entries)
    if os.path.exists(stamp_path):
        with open(stamp_path) as f:
            if f.read().strip() == stamp and all(
                os.path.isfile(os.path.join(dest, e.path)) and os.path.getsize(os.path.join(dest, e.path)) == e.size
                for e in entries
            ):
                return 0
        os.unlink(stamp_path)
    todo = []
    for e in entries:  # keep what a previous run verified
        final = os.path.join(dest, e.path)
        if os.path.isfile(final):
            if os.path.getsize(final) == e.size and file_sha256(final) == e.sha256:
                continue
            os.unlink(final)
        todo.append(e)
    errors = []
    plain = [e for e in todo if e.how != "derive"]
    with concurrent.futures.ThreadPoolExecutor(max_workers=WORKERS) as pool:
        futures = {pool.submit(fetch_entry, e, sources, dest, tmp_dir, mirror): e for e in plain}
        for fut in concurrent.futures.as_completed(futures):
            try:
                fut.result()
            except (FetchError, OSError) as err:
                errors.append(str(err))
    if not errors:
        for e in (e for e in todo if e.how == "derive"):
            try:
                derive_entry(e, sources, dest, tmp_dir, mirror)
            except (FetchError, OSError) as err:
                errors.append(str(err))
    if errors:
        errors.sort()
        more = f"\n  ... and {len(errors) - 10} more" if len(errors) > 10 else ""
        raise FetchError(f"{folder}: {len(errors)} of {len(entries)} files failed:\n  " + "\n  ".join(errors[:10]) + more)
    fd, tmp = tempfile.mkstemp(dir=tmp_dir)
    with os.fdopen(fd, "w") as f:
        f.write(stamp + "\n")
    os.replace(tmp, stamp_path)
    log(f"fetch-realdata: {folder}: {len(todo)} of {len(entries)} files fetched or made, all verified")
    return len(todo)


def remove_stale_downloads(tmp_dir, age_s=3600):
    """Temporary files an interrupted run left (never used: only verified files are renamed into place);
    recent ones may belong to a run going on beside this one."""
    if os.path.isdir(tmp_dir):
        for name in os.listdir(tmp_dir):
            path = os.path.join(tmp_dir, name)
            if time.time() - os.path.getmtime(path) > age_s:
                os.unlink(path)


def default_dest():
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(cache, "pointreggpt", "realdata")


def main(argv=None):
    ap = argparse.ArgumentParser(description="Fetches the real-data folders of the manifest, pinned by SHA-256.")
    ap.add_argument("--manifest", default=MANIFEST, help="default: scripts/data-sources/manifest.txt")
    ap.add_argument("--dest", default=default_dest(), help="default: $XDG_CACHE_HOME/pointreggpt/realdata (~/.cache/...)")
    ap.add_argument("--mirror", default=os.environ.get("POINTREGGPT_DATA_MIRROR", ""),
                    help="fetch from this server instead (default: $POINTREGGPT_DATA_MIRROR)")
    ap.add_argument("--only", action="append", help="fetch only this folder (repeatable)")
    a = ap.parse_args(argv)
    try:
        sources, entries = read_manifest(a.manifest)
        folders = sorted({e.folder for e in entries})
        for name in a.only or []:
            if name not in folders:
                raise FetchError(f"no folder '{name}' in {a.manifest} (it has {', '.join(folders)})")
        dest = os.path.abspath(a.dest)
        os.makedirs(dest, exist_ok=True)
        remove_stale_downloads(os.path.join(dest, ".fetch", "tmp"))
        failed = []
        for folder in a.only or folders:
            try:
                fetch_folder(folder, [e for e in entries if e.folder == folder], sources, dest, a.mirror,
                             lambda m: print(m, file=sys.stderr))
            except FetchError as err:
                failed.append(str(err))
        if failed:
            raise FetchError("\n".join(failed))
    except FetchError as err:
        print(f"fetch-realdata: error: {err}", file=sys.stderr)
        print("fetch-realdata: nothing unverified was kept; rerun to resume (verified files stay)", file=sys.stderr)
        return 1
    print(f"fetch-realdata: {len(a.only or folders)} folder(s) complete in {dest}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
