#!/usr/bin/env python3
"""Reads back the three export formats of `pointreggpt export` with Python only and checks them against the
rows the build wrote (read from the committed shards with pyarrow, see pair_dataset.py).

Usage: check_exports.py <dataset> <plan.json>
plan.json: {"pointreggpt": dir, "geotransformer": dir (default .pth clouds), "geotransformer_npy": dir
            (--cloud-format npy), "ply": dir,
            "exported": [pair keys the training formats hold, in order], "ply_exported": [pair keys in the ply export]}

Checks: PLY clouds (a small numpy PLY parser) and the target clouds' per-point provenance (vertex properties
`known_share`/`scene_share`/`view` in the PLY formats, `.known_share`/`.scene_share`/`.view` files in
GeoTransformer's) against the `target_known_share`/`target_scene_share`/`target_view` columns, poses and intrinsics (np.loadtxt), gt.log lines (format and
the official keep rule), the GeoTransformer export as GeoTransformer's own loader reads it (pickle.load of
metadata/train.pkl, numpy arrays, warnings as errors; then torch.load(osp.join(data_root, pcd),
weights_only=False) of each .pth cloud: a zip archive laid out as torch.save's, compared record by record
with a file torch.save writes), the .npy clouds of --cloud-format npy (np.load), and ground-truth alignment: with the stored transform, the fraction of target points
with a source point closer than 3.75 cm equals the stored overlap_target (brute force nearest neighbours).
Prints one JSON object; exits non-zero (AssertionError) on any mismatch. Run by tests/export.rs.
"""
import json
import os
import pickle
import re
import sys
import tempfile
import warnings

try:
    import numpy as np
except ImportError as e:  # a missing numpy is a failure, not a skip
    sys.exit(f"check_exports.py needs numpy ({e}); `pip install numpy` (pyarrow from scripts/install-test-deps.sh pulls it)")

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pair_dataset import committed_shards, points  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402

RADIUS = np.float32(0.0375)
VOXEL = 0.025
PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4", "float": "f4", "double": "f8",
             "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4", "float32": "f4", "float64": "f8"}


def read_ply(path):
    """The x, y, z of a binary little-endian PLY with scalar vertex properties, as float32 (N, 3)."""
    v = read_ply_vertices(path)
    return np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float32)


def read_ply_vertices(path):
    """The vertex records of a binary little-endian PLY with scalar vertex properties (a structured array)."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[0] == "ply" and "format binary_little_endian 1.0" in header, header[:3]
    count, fields, in_vertex = 0, [], False
    for line in header:
        words = line.split()
        if words[:1] == ["element"]:
            in_vertex = words[1] == "vertex"
            if in_vertex:
                count = int(words[2])
        elif words[:1] == ["property"] and in_vertex:
            fields.append((words[2], "<" + PLY_TYPES[words[1]]))
    return np.frombuffer(data, dtype=np.dtype(fields), count=count, offset=end)


def check_provenance(vertices, r, key):
    """The PLY vertex properties known_share, scene_share and view equal the row's provenance columns."""
    names = ("x", "y", "z", "known_share", "scene_share", "view")
    assert vertices.dtype.names == names, f"{key}: target PLY properties {vertices.dtype.names}"
    assert np.array_equal(vertices["known_share"], r["known_share"]), f"{key}: known_share"
    assert np.array_equal(vertices["scene_share"], r["scene_share"]), f"{key}: scene_share"
    assert np.array_equal(vertices["view"].astype(np.int8), r["view"]), f"{key}: view"


def load_rows(root):
    rows = {}
    cols = ["pair_key", "unit_index", "scene", "status", "source_points", "target_points", "t_target_from_source",
            "overlap_source", "overlap_target", "source_intrinsics", "target_known_share", "target_scene_share", "target_view"]
    for path in committed_shards(root):
        t = pq.read_table(path, columns=cols)
        for i in range(t.num_rows):
            r = {c: t.column(c)[i].as_py() for c in cols if not c.endswith("_points") and not c.startswith("target_")}
            r["source"], r["target"] = points(t.column("source_points"), i), points(t.column("target_points"), i)
            r["known_share"] = np.asarray(t.column("target_known_share")[i].as_py(), dtype=np.float32)
            r["scene_share"] = np.asarray(t.column("target_scene_share")[i].as_py(), dtype=np.float32)
            r["view"] = np.asarray(t.column("target_view")[i].as_py(), dtype=np.int8)
            n = len(r["target"])
            assert len(r["known_share"]) == len(r["scene_share"]) == len(r["view"]) == n, f"{r['pair_key']}: provenance lengths"
            r["T"] = np.asarray(r["t_target_from_source"], dtype=np.float64).reshape(4, 4)
            rows[r["pair_key"]] = r
    return rows


def move(cloud, T):
    """T·p for float32 points as the Rust library computes it: f64, m00·x + m01·y + m02·z + m03, then f32."""
    x, y, z = (cloud[:, k].astype(np.float64) for k in range(3))
    return np.stack([(T[r, 0] * x + T[r, 1] * y + T[r, 2] * z + T[r, 3]).astype(np.float32) for r in range(3)], axis=1)


def nearest_sq(queries, cloud, chunk=256):
    """Squared distance (float32, summed in the library's order) from every query to its nearest point of
    `cloud` within the radius; +inf when there is none. Brute force over an x-sorted window."""
    order = np.argsort(cloud[:, 0], kind="stable")
    sorted_cloud, xs = cloud[order], cloud[order, 0]
    qorder = np.argsort(queries[:, 0], kind="stable")
    best = np.full(len(queries), np.inf, dtype=np.float32)
    margin = np.float32(RADIUS * 1.01)
    for s in range(0, len(queries), chunk):
        idx = qorder[s:s + chunk]
        q = queries[idx]
        lo, hi = np.searchsorted(xs, q[:, 0].min() - margin), np.searchsorted(xs, q[:, 0].max() + margin, side="right")
        if lo == hi:
            continue
        p = sorted_cloud[lo:hi]
        d = [(p[None, :, k] - q[:, None, k]) for k in range(3)]
        dist = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        best[idx] = dist.min(axis=1)
    return best


def overlap_fraction(queries, cloud):
    if len(queries) == 0:
        return 0.0, np.zeros(0, np.float32)
    d = nearest_sq(queries, cloud)
    return float(np.count_nonzero(d < RADIUS * RADIUS)) / len(queries), d


def check_pointreggpt(root, rows, keys):
    tsv = [line.split("\t") for line in open(os.path.join(root, "metadata", "pairs.tsv")).read().splitlines()[1:]]
    assert [t[1] for t in tsv] == keys, "pairs.tsv lists other pairs than expected"
    gt = open(os.path.join(root, "metadata", "gt.log")).read()
    lines = gt.splitlines(keepends=True)
    pattern = re.compile(r"^scene-(\d{6})\t0\t1\t(\d\.\d{4})\t(\d\.\d{4})\n$")
    logged = {}
    for line in lines:
        m = pattern.match(line)
        assert m, f"bad gt.log line {line!r}"
        logged[f"scene-{m.group(1)}"] = (m.group(2), m.group(3))
    worst = 0.0
    for k, (scene, key, unit, in_log) in enumerate(tsv):
        r = rows[key]
        assert scene == f"scene-{k:06d}" and int(unit) == r["unit_index"] and r["status"] == "ok"
        d = os.path.join(root, "data", scene)
        src, tgt = read_ply(os.path.join(d, "sample-000000.cloud.ply")), read_ply(os.path.join(d, "sample-000001.cloud.ply"))
        check_provenance(read_ply_vertices(os.path.join(d, "sample-000001.cloud.ply")), r, key)
        assert np.array_equal(src, r["source"]), f"{key}: source cloud differs"
        pose = np.loadtxt(os.path.join(d, "sample-000001.pose.txt"))
        assert pose.shape == (4, 4) and np.abs(pose @ r["T"] - np.eye(4)).max() < 1e-9, f"{key}: pose is not inv(T)"
        assert np.abs(tgt - (r["target"].astype(np.float64) @ pose[:3, :3].T + pose[:3, 3])).max() < 1e-5, f"{key}: target not in the source frame"
        fx, fy, cx, cy = r["source_intrinsics"]
        assert np.array_equal(np.loadtxt(os.path.join(d, "camera-intrinsics.txt")), np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]))
        keep = len(src) >= 1000 and len(tgt) >= 1000 and max(r["overlap_source"], r["overlap_target"]) >= 0.1
        assert (scene in logged) == keep == (in_log == "1"), f"{key}: keep rule"
        if keep:
            assert logged[scene] == ("%.4f" % r["overlap_source"], "%.4f" % r["overlap_target"]), f"{key}: gt.log overlaps"
        # Both clouds share the source frame: target points near the source where they overlap.
        frac, dist = overlap_fraction(tgt, src)
        worst = max(worst, abs(frac - r["overlap_target"]))
        assert abs(frac - r["overlap_target"]) <= 1e-6, f"{key}: shared-frame overlap {frac} vs stored {r['overlap_target']}"
        close = np.sqrt(dist[dist < RADIUS * RADIUS])
        assert np.median(close) < VOXEL, f"{key}: median distance of overlapping points {np.median(close)}"
    return {"scenes": len(tsv), "gt_log_lines": len(lines), "max_overlap_error_shared_frame": worst}


def load_torch():
    try:
        import torch
    except ImportError as e:  # a missing torch is a failure, not a skip
        sys.exit(f"check_exports.py needs torch for the .pth clouds ({e}): scripts/install-test-deps.sh")
    return torch


def compare_with_torch_save(path, array, torch, tmp):
    """Our .pth file against the file torch.save(array) writes: the same records (under each file's own
    archive folder), the same small records, the same zip entry fields, every record's data at a multiple
    of 64 bytes, and data.pkl unpickling to the same array. Returns the pickle's numpy module."""
    import zipfile

    theirs_path = os.path.join(tmp, os.path.basename(path))
    torch.save(array, theirs_path)
    ours, theirs = zipfile.ZipFile(path), zipfile.ZipFile(theirs_path)
    stem = os.path.basename(path)[: -len(".pth")]
    names = [i.filename for i in ours.infolist()]
    assert names == [i.filename for i in theirs.infolist()], (names, theirs.namelist())
    assert all(n.startswith(stem + "/") for n in names), names
    assert ours.testzip() is None, "a record's CRC-32 differs"
    raw = open(path, "rb").read()
    for a, b in zip(ours.infolist(), theirs.infolist()):
        fields = ("compress_type", "flag_bits", "date_time", "create_system", "create_version", "extract_version", "external_attr", "internal_attr")
        assert [getattr(a, f) for f in fields] == [getattr(b, f) for f in fields], (a.filename, [getattr(a, f) for f in fields], [getattr(b, f) for f in fields])
        name_len, extra_len = int.from_bytes(raw[a.header_offset + 26:a.header_offset + 28], "little"), int.from_bytes(raw[a.header_offset + 28:a.header_offset + 30], "little")
        assert (a.header_offset + 30 + name_len + extra_len) % 64 == 0, f"{a.filename}: data not 64-aligned"
        assert raw[a.header_offset + 30 + name_len:a.header_offset + 32 + name_len] == b"FB"
        if not a.filename.endswith(("data.pkl", "serialization_id")):
            assert ours.read(a) == theirs.read(b), a.filename
    serial = ours.read(stem + "/.data/serialization_id")
    assert len(serial) == 40 and serial.isdigit(), serial
    pkl = ours.read(stem + "/data.pkl")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = pickle.loads(pkl)
    assert isinstance(back, np.ndarray) and back.dtype == array.dtype and np.array_equal(back, array)
    assert pkl[:3] == b"\x80\x02c", pkl[:3]  # protocol 2, then GLOBAL '<module>\n_reconstruct\n'
    return pkl[3:].split(b"\n", 1)[0].decode()


def check_geotransformer(root, rows, keys, loader="pth", tmp=None):
    """GeoTransformer's ThreeDMatchPairDataset reading path: metadata_root = <root>/metadata, data_root =
    <root>/data, metadata_list = pickle.load(...), then for each entry torch.load(osp.join(data_root,
    metadata['pcd0'])) (weights_only=False, which PyTorch >= 2.6 needs for numpy arrays) - or np.load for
    the .npy export - giving exactly the rows' clouds, and rotation/translation the rows' transform."""
    torch = load_torch() if loader == "pth" else None
    metadata_root, data_root = os.path.join(root, "metadata"), os.path.join(root, "data")
    with open(os.path.join(metadata_root, "train.pkl"), "rb") as f:
        raw = f.read()
    assert raw[:2] == b"\x80\x02", "not a protocol-2 pickle"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # e.g. a numpy DeprecationWarning on the array globals
        with open(os.path.join(metadata_root, "train.pkl"), "rb") as f:
            meta = pickle.load(f)
    assert isinstance(meta, list) and len(meta) == len(keys), f"{len(meta)} entries, expected {len(keys)}"
    want_keys = {"scene_name", "frag_id0", "frag_id1", "overlap", "pcd0", "pcd1", "rotation", "translation", "pcd0_known_share", "pcd0_scene_share", "pcd0_view"}
    ext = "." + loader

    def load(rel):
        assert rel.endswith(ext), rel
        path = os.path.join(data_root, rel)
        if loader == "npy":
            return np.load(path)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            return torch.load(path, weights_only=False)

    exact, compared, module = 0, 0, None
    for k, (e, key) in enumerate(zip(meta, keys)):
        r = rows[key]
        assert set(e) == want_keys, sorted(e)
        assert e["scene_name"] == r["scene"] and (e["frag_id0"], e["frag_id1"]) == (2 * k, 2 * k + 1)
        assert type(e["frag_id0"]) is int and type(e["overlap"]) is float and e["overlap"] == r["overlap_target"]
        R, t = e["rotation"], e["translation"]
        assert isinstance(R, np.ndarray) and R.dtype == np.float64 and R.shape == (3, 3) and R.flags["C_CONTIGUOUS"]
        assert isinstance(t, np.ndarray) and t.dtype == np.float64 and t.shape == (3,)
        assert np.array_equal(R, r["T"][:3, :3]) and np.array_equal(t, r["T"][:3, 3]), f"{key}: transform"
        ref, src = load(e["pcd0"]), load(e["pcd1"])
        for cloud in (ref, src):
            assert type(cloud) is np.ndarray and cloud.dtype == np.float32 and cloud.ndim == 2 and cloud.shape[1] == 3 and cloud.flags["C_CONTIGUOUS"]
        assert ref.tobytes() == r["target"].tobytes() and ref.shape == r["target"].shape, f"{key}: target cloud (pcd0) bits"
        assert src.tobytes() == r["source"].tobytes() and src.shape == r["source"].shape, f"{key}: source cloud (pcd1) bits"
        known, scene, view = load(e["pcd0_known_share"]), load(e["pcd0_scene_share"]), load(e["pcd0_view"])
        assert known.dtype == scene.dtype == np.float32 and view.dtype == np.int8, (known.dtype, scene.dtype, view.dtype)
        assert known.shape == scene.shape == view.shape == (len(ref),), (known.shape, scene.shape, view.shape)
        assert np.array_equal(known, r["known_share"]) and np.array_equal(scene, r["scene_share"]), f"{key}: provenance shares"
        assert np.array_equal(view, r["view"]), f"{key}: provenance view"
        if loader == "pth" and k < 2:
            for rel, array in ((e["pcd0"], ref), (e["pcd0_view"], view)):
                module = compare_with_torch_save(os.path.join(data_root, rel), array, torch, tmp)
                compared += 1
        # GeoTransformer's convention ref = src @ R.T + t, computed as the library does: exact overlaps.
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        moved = move(src, T)
        ov_ref, dist = overlap_fraction(ref, moved)
        ov_src, _ = overlap_fraction(moved, ref)
        assert abs(ov_ref - r["overlap_target"]) <= 1e-6, f"{key}: overlap_target {ov_ref} vs {r['overlap_target']}"
        assert abs(ov_src - r["overlap_source"]) <= 1e-6, f"{key}: overlap_source {ov_src} vs {r['overlap_source']}"
        exact += ov_ref == r["overlap_target"] and ov_src == r["overlap_source"]
        close = np.sqrt(dist[dist < RADIUS * RADIUS])
        assert np.median(close) < VOXEL, f"{key}: median distance of overlapping points {np.median(close)}"
    report = {"entries": len(meta), "overlaps_bit_exact": exact, "clouds": loader}
    if loader == "pth":
        first = os.path.join(data_root, meta[0]["pcd0"])
        # PyTorch >= 2.6 loads with weights_only=True by default, which refuses numpy arrays (as it
        # refuses GeoTransformer's own files); the allow-list docs/using-datasets.md gives lets it load.
        try:
            torch.load(first)
            refused = False
        except pickle.UnpicklingError:
            refused = True
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            from numpy.core.multiarray import _reconstruct  # no warning in numpy 1.x or 2.x (kept for pickles)

            safe = [(_reconstruct, "numpy.core.multiarray._reconstruct"), np.ndarray, np.dtype, type(np.dtype("f4")), type(np.dtype("i1"))]
            with torch.serialization.safe_globals(safe):
                allowed = torch.load(first)
                allowed_view = torch.load(os.path.join(data_root, meta[0]["pcd0_view"]))
        assert np.array_equal(allowed, rows[keys[0]]["target"]) and np.array_equal(allowed_view, rows[keys[0]]["view"])
        report.update(compared_with_torch_save=compared, pickle_module=module, weights_only_default_refuses=refused, torch=torch.__version__)
    return report


def check_ply(root, rows, keys):
    tsv = [line.split("\t") for line in open(os.path.join(root, "metadata", "pairs.tsv")).read().splitlines()[1:]]
    assert [t[1] for t in tsv] == keys, "pairs.tsv lists other pairs than expected"
    folders = sorted(n for n in os.listdir(root) if n != "metadata")
    assert folders == sorted(t[0] for t in tsv), "pair folders differ from pairs.tsv"
    for folder, key, unit, status in tsv:
        r = rows[key]
        assert status == r["status"] and int(unit) == r["unit_index"]
        d = os.path.join(root, folder)
        assert np.array_equal(read_ply(os.path.join(d, "source.ply")), r["source"]), f"{key}: source"
        assert np.array_equal(read_ply(os.path.join(d, "target.ply")), r["target"]), f"{key}: target"
        if len(r["target"]):
            check_provenance(read_ply_vertices(os.path.join(d, "target.ply")), r, key)
        assert np.array_equal(np.loadtxt(os.path.join(d, "T_target_from_source.txt")), r["T"]), f"{key}: transform"
    return {"pairs": len(tsv)}


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: check_exports.py <dataset> <plan.json>")
    with open(sys.argv[2]) as f:
        plan = json.load(f)
    rows = load_rows(sys.argv[1])
    tmp = tempfile.mkdtemp()
    print(json.dumps({
        "pointreggpt": check_pointreggpt(plan["pointreggpt"], rows, plan["exported"]),
        "geotransformer": check_geotransformer(plan["geotransformer"], rows, plan["exported"], "pth", tmp),
        "geotransformer_npy": check_geotransformer(plan["geotransformer_npy"], rows, plan["exported"], "npy"),
        "ply": check_ply(plan["ply"], rows, plan["ply_exported"]),
        "numpy": np.__version__,
    }))


if __name__ == "__main__":
    main()
