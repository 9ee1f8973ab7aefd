#!/usr/bin/env python3
"""Scores the classical depth fills a practitioner has at hand on the views `pointreggpt eval inpaint
--dump-views DIR` wrote, with the metrics of `eval inpaint` (src/training/fill_metrics.rs), computed here
independently, and prints them in one table with our rows (`eval inpaint --out CSV`) and ratios.

Peers:
- OpenCV `cv2.inpaint` Navier-Stokes and Telea, radius 5, on the float32 depth (and Telea on uint16
  millimetres, see fill_telea_mm);
- nearest valid pixel (scipy `distance_transform_edt` indices);
- IP-Basic (Ku, Harakeh, Waslander 2018, "In Defense of Classical Image Processing: Fast Depth Completion
  on the CPU"), written from the paper's description of its fast pipeline.
Every peer keeps the known pixels as they are (the exact-consistency rule of our fills).

With scenes (`eval inpaint --scene --dump-views`: NNN_scene.npy beside a view, the scene's depth at the unknown
pixels it sees), every peer also runs as the scene fill's fallback: `scene+<peer>` keeps the known and scene
pixels and fills the rest, scored on the same unknown pixels as the peer alone.

Our fills are scored from the outputs `eval inpaint --dump-views` writes beside the views (NNN_fill_<fill>.npy),
with the same code as the peers; `--ours` only brings their timing. Two tables: each row on every pixel it
fills (its coverage shown), and every row on the pixels all rows fill (IP-Basic leaves pixels far from any
known depth empty, so alone its scores cover the easy part of a large hole).

`rough` is the mean |4-neighbour Laplacian| of a row's depth on the filled pixels whose neighbours are filled,
over the captured depth's on the same pixels: 1 is as rough as the sensor's own depth, below 1 smoother
(a noise-free surface), above rougher.

Usage: fill_peers.py --views DIR/<correction> [--ours eval.csv] [--label TEXT]
"""
import argparse
import csv
import json
import os
import sys
import time

import numpy as np
import cv2
from scipy import ndimage
from scipy.spatial import cKDTree

PENETRATION_M = 0.05
EDGE_BAND_PX = 3
EDGE_JUMP_REL = 0.05
FLYING_M = 0.05


# ---------------------------------------------------------------- peers

def fill_ns(cond, known):
    return cv2.inpaint(cond.astype(np.float32), (~known).astype(np.uint8), 5, cv2.INPAINT_NS)


def fill_telea(cond, known):
    return cv2.inpaint(cond.astype(np.float32), (~known).astype(np.uint8), 5, cv2.INPAINT_TELEA)


def fill_telea_mm(cond, known):
    """Telea on uint16 millimetres, as a depth sensor stores them: OpenCV 4.14's Telea on float32 input
    returns values off the known range even on a constant image, so the float32 row alone would be unfair."""
    mm = np.clip(np.round(cond * 1000.0), 0, 65535).astype(np.uint16)
    return cv2.inpaint(mm, (~known).astype(np.uint8), 5, cv2.INPAINT_TELEA).astype(np.float32) / 1000.0


def fill_nearest(cond, known):
    src = known & (cond > 0)
    if not src.any():
        return np.zeros_like(cond)
    _, (ri, ci) = ndimage.distance_transform_edt(~src, return_indices=True)
    return cond[ri, ci]


def _kernel(n, diamond=False):
    k = np.ones((n, n), np.uint8)
    if diamond:
        r = n // 2
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        k = (np.abs(yy) + np.abs(xx) <= r).astype(np.uint8)
    return k


def fill_ip_basic(cond, known, max_depth=100.0):
    """IP-Basic's fast pipeline as the paper lists it: invert, diamond dilation, small closing, small and
    large hole dilations, column extension to the top, median and Gaussian blurs, invert back."""
    d = np.where(known & (cond > 0), cond, 0).astype(np.float32)
    valid = d > 0.1
    # 1. Inversion: nearer = larger, so dilations (max filters) keep the foreground and empty stays 0.
    d[valid] = max_depth - d[valid]
    # 2. Dilation with a 5x5 diamond kernel.
    d = cv2.dilate(d, _kernel(5, diamond=True))
    # 3. Small hole closure: 5x5 full-kernel morphological close.
    d = cv2.morphologyEx(d, cv2.MORPH_CLOSE, _kernel(5))
    # 4. Small hole fill: 7x7 dilation applied to empty pixels only.
    empty = d < 0.1
    dil = cv2.dilate(d, _kernel(7))
    d[empty] = dil[empty]
    # 5. Extension to the top of the frame: each column's top value upward.
    h, w = d.shape
    has = d > 0.1
    top = np.where(has.any(axis=0), has.argmax(axis=0), h)
    for c in range(w):
        if top[c] < h:
            d[:top[c], c] = d[top[c], c]
    # 6. Large hole fill: 31x31 dilation on empty pixels.
    empty = d < 0.1
    dil = cv2.dilate(d, _kernel(31))
    d[empty] = dil[empty]
    # 7. Median blur (5x5) against outliers, then a 5x5 Gaussian blur, on the filled pixels.
    med = cv2.medianBlur(d, 5)
    filled = d > 0.1
    d[filled] = med[filled]
    blur = cv2.GaussianBlur(d, (5, 5), 0)
    filled = d > 0.1
    d[filled] = blur[filled]
    # 8. Invert back.
    out = np.zeros_like(d)
    filled = d > 0.1
    out[filled] = max_depth - d[filled]
    return out


def fill_ip_basic_nearest(cond, known):
    """IP-Basic leaves the pixels its 31x31 dilation cannot reach empty (most of a large re-projection hole);
    here they get the nearest valid pixel, so the row fills every pixel as the others do."""
    out = fill_ip_basic(cond, known)
    return np.where(out > 0, out, fill_nearest(cond, known))


PEERS = [("opencv_ns", fill_ns), ("opencv_telea", fill_telea), ("opencv_telea_u16mm", fill_telea_mm), ("nearest_edt", fill_nearest),
         ("ip_basic", fill_ip_basic), ("ip_basic+nearest", fill_ip_basic_nearest)]


# ---------------------------------------------------------------- metrics (fill_metrics.rs, independently)

def edge_band(g, lo, hi):
    valid = (g > lo) & (g < hi)
    edge = np.zeros_like(valid)
    for a, b, sl_a, sl_b in [(g[:, :-1], g[:, 1:], (slice(None), slice(None, -1)), (slice(None), slice(1, None))),
                             (g[:-1, :], g[1:, :], (slice(None, -1), slice(None)), (slice(1, None), slice(None)))]:
        va, vb = valid[sl_a], valid[sl_b]
        j = va & vb & (np.abs(a - b) > EDGE_JUMP_REL * np.minimum(a, b))
        edge[sl_a] |= j
        edge[sl_b] |= j
    n = 2 * EDGE_BAND_PX + 1
    return ndimage.maximum_filter(edge.astype(np.uint8), size=n, mode="constant", cval=0).astype(bool)


class Scores:
    def __init__(self):
        self.views = 0
        self.pixels = 0
        self.unknown_all = 0
        self.unknown = 0
        self.err = {"fill": [], "band": []}
        self.flying = 0
        self.cloud = 0.0
        self.seconds = 0.0
        self.rough = [0.0, 0.0]  # |4-neighbour Laplacian| summed over interior filled pixels: the fill's, the capture's

    def add(self, known, out, g, k, lo, hi, only=None):
        """Scores one view; `only` (bool, H x W) restricts the filled pixels scored (the common pixels)."""
        self.views += 1
        self.pixels += g.size
        self.unknown_all += int((~known).sum())
        gv = (g > lo) & (g < hi)
        unk = ~known & gv
        self.unknown += int(unk.sum())
        sel = unk & (out > lo) & (out < hi)
        if only is not None:
            sel &= only
        z, t = out[sel].astype(np.float64), g[sel].astype(np.float64)
        self.err["fill"].append(np.stack([z, t]))
        band = edge_band(g, lo, hi)
        bs = sel & band
        self.err["band"].append(np.stack([out[bs].astype(np.float64), g[bs].astype(np.float64)]))
        gi = np.where(gv, g, np.inf)
        ga = np.where(gv, g, -np.inf)
        fg = ndimage.minimum_filter(gi, size=3, mode="constant", cval=np.inf)
        bg = ndimage.maximum_filter(ga, size=3, mode="constant", cval=-np.inf)
        self.flying += int(((np.abs(out - fg) > FLYING_M) & (np.abs(out - bg) > FLYING_M) & sel).sum())
        # Roughness: on filled pixels whose 4 neighbours are filled and captured too, the mean |Laplacian|
        # of the fill against the capture's on the same pixels (1: as rough as the sensor; below: smoother).
        inner = np.zeros_like(sel)
        inner[1:-1, 1:-1] = sel[1:-1, 1:-1] & sel[:-2, 1:-1] & sel[2:, 1:-1] & sel[1:-1, :-2] & sel[1:-1, 2:]
        lap = lambda d: np.abs(4 * d[1:-1, 1:-1] - d[:-2, 1:-1] - d[2:, 1:-1] - d[1:-1, :-2] - d[1:-1, 2:])
        m = inner[1:-1, 1:-1]
        self.rough[0] += float(lap(out.astype(np.float64))[m].sum())
        self.rough[1] += float(lap(g.astype(np.float64))[m].sum())
        if sel.any():
            rr, cc = np.nonzero(gv)
            cloud = np.stack([(cc - k["cx"]) / k["fx"] * g[gv], (rr - k["cy"]) / k["fy"] * g[gv], g[gv]], 1)
            rr, cc = np.nonzero(sel)
            zz = out[sel]
            q = np.stack([(cc - k["cx"]) / k["fx"] * zz, (rr - k["cy"]) / k["fy"] * zz, zz], 1)
            d, _ = cKDTree(cloud).query(q)
            self.cloud += float(d.sum())

    @staticmethod
    def _three(pairs):
        if not pairs:
            return float("nan"), float("nan"), float("nan"), 0
        z, t = np.concatenate(pairs, axis=1)
        n = max(len(z), 1)
        absrel = float((np.abs(z - t) / t).sum() / n)
        rmse = float(np.sqrt(((z - t) ** 2).sum() / n))
        delta = float((np.maximum(z / t, t / z) < 1.25).sum() / n)
        return absrel, rmse, delta, len(z)

    def row(self):
        a, r, d, n = self._three(self.err["fill"])
        ba, br, bd, _ = self._three(self.err["band"])
        return {
            "views": self.views, "unknown_share": self.unknown_all / max(self.pixels, 1),
            "fill_coverage": n / max(self.unknown, 1), "fill_abs_rel": a, "fill_rmse_m": r, "fill_delta_1_25": d,
            "edge_abs_rel": ba, "edge_rmse_m": br, "edge_delta_1_25": bd,
            "flying_share": self.flying / max(n, 1), "cloud_distance_m": self.cloud / max(n, 1),
            "ms_per_view": 1000.0 * self.seconds / max(self.views, 1),
            "roughness_ratio": self.rough[0] / self.rough[1] if self.rough[1] > 0 else float("nan"),
        }


def load_views(folder):
    meta_path = os.path.join(folder, "views.json")
    try:
        with open(meta_path) as f:
            meta = json.load(f)
    except OSError as e:
        sys.exit(f"fill_peers: cannot read {meta_path}: {e} (write it with `pointreggpt eval inpaint --dump-views`)")
    views = []
    for v in meta["views"]:
        i = v["index"]
        arr = {n: np.load(os.path.join(folder, f"{i:03d}_{n}.npy")) for n in ("condition", "known", "captured")}
        fills = {f[len(f"{i:03d}_fill_"):-4]: np.load(os.path.join(folder, f))
                 for f in sorted(os.listdir(folder)) if f.startswith(f"{i:03d}_fill_") and f.endswith(".npy")}
        scene_path = os.path.join(folder, f"{i:03d}_scene.npy")
        v["scene"] = np.load(scene_path) if os.path.exists(scene_path) else None
        views.append((arr["condition"], arr["known"].astype(bool), arr["captured"], v, fills))
    return meta, views


def after_scene(fn):
    """`fn` as the scene fill's fallback: the scene's pixels join the known ones, `fn` fills the rest."""
    def fill(cond, known, scene):
        seen = scene > 0
        return fn(np.where(seen, scene, cond).astype(np.float32), known | seen)
    return fill


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", required=True, help="one correction's folder of `eval inpaint --dump-views`")
    ap.add_argument("--ours", help="`eval inpaint --out` CSV: the ms/view of our fills (their scores come from the dumped fills)")
    ap.add_argument("--label", default="", help="heading of the table")
    ap.add_argument("--csv", help="write the peers' rows here")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    meta, views = load_views(args.views)
    lo, hi = meta["depth_range"]
    corr = meta["correction"]
    # Every row's output per view: ours from the dumped fills (`eval inpaint --dump-views`), peers run here.
    outputs = {}
    for name in sorted(views[0][4]):
        outputs["ours: " + name] = ([fills[name] for *_, fills in views], None)
    with_scene = all(v["scene"] is not None for _, _, _, v, _ in views)
    for name, fn in PEERS:
        for scene in ([False, True] if with_scene else [False]):
            outs, seconds = [], 0.0
            for cond, known, g, v, _ in views:
                t0 = time.perf_counter()
                out = after_scene(fn)(cond, known, v["scene"]) if scene else fn(cond, known)
                out = np.where(known, cond, out).astype(np.float32)
                seconds += time.perf_counter() - t0
                outs.append(out)
            outputs[("peer: scene+" if scene else "peer: ") + name] = (outs, seconds)
    timing, theirs = {}, {}
    if args.ours:
        with open(args.ours) as f:
            for r in csv.DictReader(f):
                if r["correction"] == corr:
                    timing["ours: " + r["fill"].replace("/", "-")] = float(r["ms_per_view"])
                    theirs["ours: " + r["fill"].replace("/", "-")] = float(r["fill_abs_rel"])
    if not outputs:
        sys.exit("fill_peers: nothing to score")
    # The pixels every row fills (IP-Basic leaves most of a large hole empty): the fair common ground.
    common = [np.ones_like(views[i][1]) for i in range(len(views))]
    for outs, _ in outputs.values():
        for i, out in enumerate(outs):
            common[i] &= (out > lo) & (out < hi)
    tables = []
    for title, only in (("every pixel each row fills", None), ("the pixels every row fills", common)):
        rows = []
        for name, (outs, seconds) in outputs.items():
            sc = Scores()
            for i, (cond, known, g, v, _) in enumerate(views):
                sc.add(known, outs[i], g, v, lo, hi, None if only is None else only[i])
            sc.seconds = seconds if seconds is not None else timing.get(name, float("nan")) * len(views) / 1000.0
            rows.append((name, sc.row()))
        tables.append((title, rows))
    rows = tables[0][1]
    # Cross-check: the AbsRel computed here of our dumped fills is the one `eval inpaint` computed in Rust.
    for name, r in rows:
        if name in theirs and abs(theirs[name] - r["fill_abs_rel"]) > 1e-4:
            print(f"warning: {name}: AbsRel {r['fill_abs_rel']:.6f} here, {theirs[name]:.6f} in {args.ours}", file=sys.stderr)
    h, w = views[0][2].shape
    for title, rows in tables:
        # The reference row: our best AbsRel among the rows that fill (nearly) every hole pixel.
        full = [r for r in rows if r[1]["fill_coverage"] > 0.99] or rows
        ours = [r for r in full if r[0].startswith("ours")]
        best = min(ours or full, key=lambda r: r[1]["fill_abs_rel"])
        print(f"{args.label} correction {corr}: {len(views)} views {w}x{h}, unknown share {rows[-1][1]['unknown_share']:.1%}; "
              f"scored on {title}; ratios = row / {best[0]} (above 1: worse than it)")
        print(f"{'fill':<28} {'cover':>6} {'AbsRel':>7} {'x':>5} {'RMSE m':>7} {'x':>5} {'d<1.25':>7} {'edgeAR':>7} {'edgeRM':>7} "
              f"{'flying':>7} {'cloud cm':>8} {'ms/view':>8} {'ms/256²':>8} {'rough':>6}")
        b = best[1]
        for name, r in rows:
            ms256 = r["ms_per_view"] * 65536 / (w * h)
            print(f"{name:<28} {100 * r['fill_coverage']:5.1f}% {r['fill_abs_rel']:7.4f} {r['fill_abs_rel'] / b['fill_abs_rel']:5.2f} "
                  f"{r['fill_rmse_m']:7.3f} {r['fill_rmse_m'] / b['fill_rmse_m']:5.2f} {100 * r['fill_delta_1_25']:6.1f}% "
                  f"{r['edge_abs_rel']:7.4f} {r['edge_rmse_m']:7.3f} {100 * r['flying_share']:6.1f}% "
                  f"{100 * r['cloud_distance_m']:8.2f} {r['ms_per_view']:8.1f} {ms256:8.1f} {r['roughness_ratio']:6.2f}")
        print()
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            wr = csv.writer(f)
            keys = list(rows[-1][1].keys())
            wr.writerow(["correction", "fill", "pixels"] + keys)
            for (title, rows), pixels in zip(tables, ("each", "common")):
                for name, r in rows:
                    wr.writerow([corr, name, pixels] + [r.get(k, "") for k in keys])


if __name__ == "__main__":
    main()
