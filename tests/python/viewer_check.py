#!/usr/bin/env python3
"""Checks `pointreggpt_data.show_pair` (the viewer extra, rerun-sdk) headless: it writes an .rrd file,
which is read back with Rerun's own reader (rerun.chunk.RrdReader). Run by tests/python_package.rs.

Usage: viewer_check.py <plan.json>

plan.json:
  dataset   a folder: a version-3 dataset built with a scene method and a fill (so its targets have
            re-projected, scene and made-up points) and depth maps stored
  scratch   a folder to write the recordings in (the working folder of the no-display call)

Checks: with no display (DISPLAY and WAYLAND_DISPLAY unset) and no `save`, show_pair writes
pair-<unit>.rrd in the working folder; the recording holds the source cloud as stored, the target cloud
in the source frame (compared with inv(T) applied in float64 here, to 1e-5 m) split into the three
provenance kinds with the counts computed here from the stored shares, one colour per kind, and the four
depth images with the PNGs' pixels (decoded by Pillow here); a pair dict made here with known shares of
each kind lands in the right entities. Prints one JSON object; fails (never skips) when rerun is missing.
"""
import json
import os
import sys

import numpy as np

try:
    import rerun  # noqa: F401
    from rerun.chunk import RrdReader
except ImportError as e:
    sys.exit(f"viewer_check.py needs the viewer extra (pip install \"./python[viewer]\": rerun-sdk): {e}")
from PIL import Image
import io

import pointreggpt_data as prd
from pointreggpt_data.viewer import KINDS

PNGS = {"source_depth": "source_depth_png", "condition_depth": "condition_depth_png", "target_depth": "target_depth_png",
        "known_mask": "known_mask_png"}


def recording(path):
    """{entity path: {column: values of its (single) row}} from Rerun's reader."""
    out = {}
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        row = {name: batch.column(i)[0].as_py() if batch.num_rows else None for i, name in enumerate(batch.schema.names)}
        if chunk.entity_path in out:
            out[chunk.entity_path].update(row)
        else:
            out[chunk.entity_path] = row
    return out


def points(row):
    return np.array(row["Points3D:positions"], dtype=np.float32).reshape(-1, 3)


def colours(row):
    c = np.array(row["Points3D:colors"], dtype=np.uint64)  # packed 0xRRGGBBAA
    return {(int(v >> 24) & 255, int(v >> 16) & 255, int(v >> 8) & 255) for v in c}


def expected_kinds(known, scene):
    made = 1.0 - known.astype(np.float64) - scene.astype(np.float64)
    kinds = []
    for k, s, m in zip(known.astype(np.float64), scene.astype(np.float64), made):
        best = max(k, s, min(max(m, 0.0), 1.0))
        kinds.append(0 if k == best else 1 if s == best else 2)
    return np.array(kinds, dtype=np.int64)


def check_file(path, pair):
    rec = recording(path)
    src = pair["source_points"]
    got = points(rec["/world/source"])
    assert got.tobytes() == src.tobytes(), "world/source is not the stored source cloud"
    T = pair["T_target_from_source"]
    tgt = pair["target_points"].astype(np.float64)
    moved = (np.linalg.inv(T) @ np.c_[tgt, np.ones(len(tgt))].T).T[:, :3]
    kinds = expected_kinds(pair["target_known_share"], pair["target_scene_share"])
    counts = {}
    for k, (name, colour) in enumerate(KINDS):
        row = rec[f"/world/target/{name}"]
        p = points(row)
        want = moved[kinds == k]
        assert p.shape == want.shape, f"{name}: {len(p)} points, {len(want)} expected from the stored shares"
        assert np.abs(p - want).max(initial=0) < 1e-5, f"{name}: points not in the source frame"
        if len(p):
            assert colours(row) == {colour}, f"{name}: colours {colours(row)}, not {colour}"
        counts[name] = len(p)
    for name, column in PNGS.items():
        row = rec[f"/images/{name}"]
        key = "Image:buffer" if name == "known_mask" else "DepthImage:buffer"
        want = np.asarray(Image.open(io.BytesIO(pair[column])))
        buf = np.array(row[key], dtype=np.uint8).tobytes()
        assert buf == want.astype(np.uint8 if name == "known_mask" else np.uint16).tobytes(), f"images/{name}: not the PNG's pixels"
    assert pair["pair_key"] in rec["/pair"]["TextDocument:text"][0], rec["/pair"]
    return counts


def main():
    plan = json.load(open(sys.argv[1]))
    os.environ.pop("DISPLAY", None)
    os.environ.pop("WAYLAND_DISPLAY", None)
    os.chdir(plan["scratch"])
    ds = prd.open_dataset(plan["dataset"])
    # The ok pair with the most made-up points: every kind present.
    best, score = None, -1
    for p in ds.pairs(columns=list(PNGS.values())):
        kinds = expected_kinds(p["target_known_share"], p["target_scene_share"])
        n = np.bincount(kinds, minlength=3)
        if n.min() > score:
            best, score = p, n.min()
    assert score > 0, "no pair with re-projected, scene and made-up points: build with a scene method and a fill"
    # No display, no `save`: a file in the working folder, by pair key.
    path = prd.show_pair(plan["dataset"], best["pair_key"])
    assert path == f"pair-{best['unit_index']}.rrd" and os.path.getsize(path) > 0, path
    counts = check_file(path, best)
    # By unit index, to a named file; the same recording.
    named = prd.show_pair(ds, best["unit_index"], save=os.path.join(plan["scratch"], "named.rrd"))
    assert check_file(named, best) == counts
    # A pair made here: known shares 1, scene 1, neither (made up), a known/scene tie (re-projected first),
    # and a point mostly made up.
    made = {
        "pair_key": "made#0", "unit_index": 0, "status": "ok", "overlap_source": 1.0, "overlap_target": 1.0,
        "source_points": np.zeros((2, 3), np.float32), "target_points": np.arange(15, dtype=np.float32).reshape(5, 3),
        "T_target_from_source": np.eye(4), "target_known_share": np.array([1, 0, 0, 0.5, 0.2], np.float32),
        "target_scene_share": np.array([0, 1, 0, 0.5, 0.3], np.float32), "target_view": np.zeros(5, np.int8),
    }
    rec = recording(prd.show_pair(made, save="made.rrd"))
    got = {name: points(rec[f"/world/target/{name}"]).tolist() for name, _ in KINDS}
    t = made["target_points"].tolist()
    assert got == {"reprojected": [t[0], t[3]], "scene": [t[1]], "made_up": [t[2], t[4]]}, got
    assert not any(k.startswith("/images") for k in rec), "images logged for a pair without depth maps"
    print(json.dumps({"pair": best["pair_key"], "file": path, "counts": counts, "bytes": os.path.getsize(path)}))


if __name__ == "__main__":
    main()
