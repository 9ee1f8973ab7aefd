#!/usr/bin/env python3
"""Python peers of the geometry benchmark (driven by benchmarks/geometry.rs).

Usage: geometry_peers.py DIR

DIR holds the exact inputs the Rust side timed, as .npy files:
  depth.npy         float32 (H, W)  depth in metres, 0 = no depth
  intrinsics.npy    float64 [fx, fy, cx, cy]
  points.npy        float32 (N, 3)  the back-projected frame (input of z-buffer and voxel)
  pose_reproj.npy   float64 (4, 4)  t_target_from_source for the z-buffer
  src.npy, tgt.npy  float32 (n, 3)  the two voxelised clouds of the overlap
  pose_overlap.npy  float64 (4, 4)  t_target_from_source for the overlap
  params.npy        float64 [near, far, voxel, radius, reps]

Prints one tab-separated line per measurement, `op <TAB> peer <TAB> ms <TAB> result`, where ms is
the median wall time of `reps` runs after warm-up (time.perf_counter), or `n/a` with a reason in
the result field. Lines starting with `info` carry versions and thread counts.
"""

import os
import statistics
import sys
import time


def emit(*fields):
    print("\t".join(str(f) for f in fields), flush=True)


def median_ms(fn, reps, warmup=2):
    """Median wall time of fn() in ms after `warmup` calls, and fn's last result."""
    out = None
    for _ in range(warmup):
        out = fn()
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3, out


def run(op, peer, fn, describe, reps, warmup=2):
    """Times one peer and prints its line; a peer that raises is reported, not fatal."""
    try:
        ms, out = median_ms(fn, reps, warmup)
        emit(op, peer, f"{ms:.4f}", describe(out))
    except Exception as e:  # noqa: BLE001 - a broken peer must not hide the others
        emit(op, peer, "n/a", f"failed: {type(e).__name__}: {e}".replace("\t", " ").replace("\n", " "))


def missing(op, peer):
    emit(op, peer, "n/a", "not installed")


def try_import(name):
    try:
        return __import__(name)
    except Exception:  # noqa: BLE001 - ImportError, or a broken shared library
        return None


# ---------------------------------------------------------------------------------------------
# Inputs


class Inputs:
    def __init__(self, d, np):
        load = lambda name: np.load(os.path.join(d, name))  # noqa: E731
        self.depth = load("depth.npy")
        self.fx, self.fy, self.cx, self.cy = (float(v) for v in load("intrinsics.npy"))
        self.points = load("points.npy")
        self.pose_reproj = load("pose_reproj.npy")
        self.src = load("src.npy")
        self.tgt = load("tgt.npy")
        self.pose_overlap = load("pose_overlap.npy")
        near, far, voxel, radius, reps = load("params.npy")
        self.near, self.far, self.voxel, self.radius = float(near), float(far), float(voxel), float(radius)
        self.reps = int(reps)
        self.height, self.width = self.depth.shape

    def k_matrix(self, np):
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)


def transform(np, points, pose):
    """pose · p for each row (float64 math, float32 result), as the Rust transform_points."""
    return (points.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# 1. depth -> points


def bench_backproject(np, o3d, x):
    op = "backproject"

    def numpy_backproject():
        z = x.depth
        valid = (z > x.near) & (z < x.far)
        ax = ((np.arange(x.width) - x.cx) / x.fx).astype(np.float32)
        ay = ((np.arange(x.height) - x.cy) / x.fy).astype(np.float32)
        zz = z[valid]
        px = (ax[None, :] * z)[valid]
        py = (ay[:, None] * z)[valid]
        return np.stack([px, py, zz], axis=1)

    run(op, "numpy", numpy_backproject, lambda p: f"points={len(p)}", x.reps)
    if o3d is None:
        missing(op, "open3d legacy create_from_depth_image")
        missing(op, "open3d tensor create_from_depth_image")
        return
    # Open3D keeps 0 < z < depth_trunc (no near bound), so its count can exceed ours.
    intr = o3d.camera.PinholeCameraIntrinsic(x.width, x.height, x.fx, x.fy, x.cx, x.cy)
    image = o3d.geometry.Image(np.ascontiguousarray(x.depth))
    run(
        op,
        "open3d legacy create_from_depth_image",
        lambda: o3d.geometry.PointCloud.create_from_depth_image(image, intr, depth_scale=1.0, depth_trunc=x.far),
        lambda pc: f"points={len(pc.points)}",
        x.reps,
    )
    timage = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(x.depth)))
    tk = o3d.core.Tensor(x.k_matrix(np))
    run(
        op,
        "open3d tensor create_from_depth_image",
        lambda: o3d.t.geometry.PointCloud.create_from_depth_image(timage, tk, depth_scale=1.0, depth_max=x.far),
        lambda pc: f"points={len(pc.point.positions)}",
        x.reps,
    )


# ---------------------------------------------------------------------------------------------
# 2. z-buffer re-projection


def numpy_zbuffer(np, x):
    p = x.points.astype(np.float64) @ x.pose_reproj[:3, :3].T + x.pose_reproj[:3, 3]
    z = p[:, 2]
    zf = z.astype(np.float32)
    front = zf > 0
    u = np.rint(p[front, 0] * x.fx / z[front] + x.cx)
    v = np.rint(p[front, 1] * x.fy / z[front] + x.cy)
    inside = (u >= 0) & (v >= 0) & (u < x.width) & (v < x.height)
    pixel = v[inside].astype(np.int64) * x.width + u[inside].astype(np.int64)
    zbuf = np.full(x.width * x.height, np.inf, dtype=np.float32)
    np.minimum.at(zbuf, pixel, zf[front][inside])
    return np.where(np.isinf(zbuf), 0.0, zbuf).reshape(x.height, x.width)


def numpy_sort_zbuffer(np, x):
    """The other numpy idiom: sort far-to-near, then a fancy assignment (the last write, the nearest, wins)."""
    p = x.points.astype(np.float64) @ x.pose_reproj[:3, :3].T + x.pose_reproj[:3, 3]
    z = p[:, 2]
    zf = z.astype(np.float32)
    front = zf > 0
    u = np.rint(p[front, 0] * x.fx / z[front] + x.cx)
    v = np.rint(p[front, 1] * x.fy / z[front] + x.cy)
    inside = (u >= 0) & (v >= 0) & (u < x.width) & (v < x.height)
    pixel = v[inside].astype(np.int64) * x.width + u[inside].astype(np.int64)
    depth = zf[front][inside]
    order = np.argsort(-depth, kind="stable")
    zbuf = np.zeros(x.width * x.height, dtype=np.float32)
    zbuf[pixel[order]] = depth[order]
    return zbuf.reshape(x.height, x.width)


def make_numba_zbuffer(numba, np):
    @numba.njit(cache=False)
    def zbuffer(points, m, fx, fy, cx, cy, width, height):
        out = np.zeros(width * height, dtype=np.float32)
        for i in range(points.shape[0]):
            px, py, pz = np.float64(points[i, 0]), np.float64(points[i, 1]), np.float64(points[i, 2])
            zc = m[2, 0] * px + m[2, 1] * py + m[2, 2] * pz + m[2, 3]
            zf = np.float32(zc)
            if not zf > 0:
                continue
            xc = m[0, 0] * px + m[0, 1] * py + m[0, 2] * pz + m[0, 3]
            yc = m[1, 0] * px + m[1, 1] * py + m[1, 2] * pz + m[1, 3]
            u = np.rint(xc * fx / zc + cx)
            v = np.rint(yc * fy / zc + cy)
            if u >= 0 and v >= 0 and u < width and v < height:
                k = int(v) * width + int(u)
                if out[k] == 0 or zf < out[k]:
                    out[k] = zf
        return out.reshape(height, width)

    return zbuffer


def bench_zbuffer(np, numba, o3d, x):
    op = "zbuffer"
    known = lambda d: f"known={int(np.count_nonzero(d))}"  # noqa: E731
    run(op, "numpy minimum.at", lambda: numpy_zbuffer(np, x), known, max(5, x.reps // 2))
    run(op, "numpy argsort+assign", lambda: numpy_sort_zbuffer(np, x), known, max(5, x.reps // 2))
    if numba is None:
        missing(op, "numba njit")
    else:
        zb = make_numba_zbuffer(numba, np)
        pts, m = np.ascontiguousarray(x.points), np.ascontiguousarray(x.pose_reproj)
        run(op, "numba njit", lambda: zb(pts, m, x.fx, x.fy, x.cx, x.cy, x.width, x.height), known, x.reps)
    if o3d is None:
        missing(op, "open3d tensor project_to_depth_image")
        return
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.ascontiguousarray(x.points)))
    tk = o3d.core.Tensor(x.k_matrix(np))
    ext = o3d.core.Tensor(np.ascontiguousarray(x.pose_reproj))
    run(
        op,
        "open3d tensor project_to_depth_image",
        lambda: cloud.project_to_depth_image(x.width, x.height, tk, ext, depth_scale=1.0, depth_max=1e4),
        lambda img: known(np.asarray(img.as_tensor().numpy())),
        x.reps,
    )


# ---------------------------------------------------------------------------------------------
# 3. voxel downsampling


def numpy_voxel(np, points, voxel):
    """Centroid per voxel floor(p / voxel) (origin 0, as ours): packed int64 keys + np.unique."""
    cell = np.floor(points.astype(np.float64) / voxel).astype(np.int64)
    cell -= cell.min(axis=0)
    dims = cell.max(axis=0) + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    sums = [np.bincount(inverse, weights=points[:, a], minlength=len(counts)) for a in range(3)]
    return (np.stack(sums, axis=1) / counts[:, None]).astype(np.float32)


def bench_voxel(np, o3d, x):
    op = "voxel"
    run(op, "numpy unique", lambda: numpy_voxel(np, x.points, x.voxel), lambda v: f"voxels={len(v)}", max(5, x.reps // 2))
    if o3d is None:
        missing(op, "open3d legacy voxel_down_sample")
        missing(op, "open3d tensor voxel_down_sample")
        return
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(x.points.astype(np.float64)))
    run(
        op,
        "open3d legacy voxel_down_sample",
        lambda: legacy.voxel_down_sample(x.voxel),
        lambda pc: f"voxels={len(pc.points)}",
        x.reps,
    )
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.ascontiguousarray(x.points)))
    run(
        op,
        "open3d tensor voxel_down_sample",
        lambda: tensor.voxel_down_sample(x.voxel),
        lambda pc: f"voxels={len(pc.point.positions)}",
        x.reps,
    )


# ---------------------------------------------------------------------------------------------
# 4. overlap (both directions; every peer includes moving the source into the target frame)


def ratios(hit_src, hit_tgt):
    return f"src={float(hit_src.mean()):.6f} tgt={float(hit_tgt.mean()):.6f}"


def bench_overlap(np, x):
    op = "overlap"
    r = x.radius
    scipy_spatial = try_import("scipy.spatial")
    if scipy_spatial is None:
        missing(op, "scipy cKDTree (workers=-1)")
    else:
        from scipy.spatial import cKDTree

        def ckdtree():
            moved = transform(np, x.src, x.pose_overlap)
            d_src, _ = cKDTree(x.tgt).query(moved, k=1, distance_upper_bound=r, workers=-1)
            d_tgt, _ = cKDTree(moved).query(x.tgt, k=1, distance_upper_bound=r, workers=-1)
            return d_src < r, d_tgt < r

        run(op, "scipy cKDTree (workers=-1)", ckdtree, lambda h: ratios(*h), x.reps)

    pykdtree_kdtree = try_import("pykdtree.kdtree")
    if pykdtree_kdtree is None:
        missing(op, "pykdtree")
    else:
        from pykdtree.kdtree import KDTree

        def pykd():
            moved = transform(np, x.src, x.pose_overlap)
            d_src, _ = KDTree(x.tgt).query(moved, k=1, distance_upper_bound=r)
            d_tgt, _ = KDTree(moved).query(x.tgt, k=1, distance_upper_bound=r)
            return d_src < r, d_tgt < r

        run(op, "pykdtree", pykd, lambda h: ratios(*h), x.reps)


def bench_overlap_open3d(np, o3d, x):
    op = "overlap"
    if o3d is None:
        for peer in ("open3d compute_point_cloud_distance", "open3d tensor NNS hybrid", "open3d KDTreeFlann loop"):
            missing(op, peer)
        return
    r = x.radius
    vec = o3d.utility.Vector3dVector
    tgt_legacy = o3d.geometry.PointCloud(vec(x.tgt.astype(np.float64)))

    def distance():
        moved = o3d.geometry.PointCloud(vec(transform(np, x.src, x.pose_overlap).astype(np.float64)))
        d_src = np.asarray(moved.compute_point_cloud_distance(tgt_legacy))
        d_tgt = np.asarray(tgt_legacy.compute_point_cloud_distance(moved))
        return d_src < r, d_tgt < r

    run(op, "open3d compute_point_cloud_distance", distance, lambda h: ratios(*h), x.reps)

    tgt_tensor = o3d.core.Tensor(np.ascontiguousarray(x.tgt))

    def hybrid(points, queries):
        nns = o3d.core.nns.NearestNeighborSearch(points)
        nns.hybrid_index(r)
        _, _, counts = nns.hybrid_search(queries, r, 1)
        return counts.numpy() > 0

    def tensor_nns():
        moved = o3d.core.Tensor(transform(np, x.src, x.pose_overlap))
        return hybrid(tgt_tensor, moved), hybrid(moved, tgt_tensor)

    run(op, "open3d tensor NNS hybrid", tensor_nns, lambda h: ratios(*h), x.reps)

    def has_neighbor(tree, queries):
        return np.array([tree.search_hybrid_vector_3d(q, r, 1)[0] > 0 for q in queries])

    def flann_loop():
        moved64 = transform(np, x.src, x.pose_overlap).astype(np.float64)
        moved = o3d.geometry.PointCloud(vec(moved64))
        tgt64 = x.tgt.astype(np.float64)
        hit_src = has_neighbor(o3d.geometry.KDTreeFlann(tgt_legacy), moved64)
        hit_tgt = has_neighbor(o3d.geometry.KDTreeFlann(moved), tgt64)
        return hit_src, hit_tgt

    run(op, "open3d KDTreeFlann loop", flann_loop, lambda h: ratios(*h), 3, warmup=1)


# ---------------------------------------------------------------------------------------------


def info(np, numba, o3d):
    emit("info", "python", sys.version.split()[0])
    emit("info", "numpy", np.__version__)
    from importlib import metadata

    for name in ("scipy", "pykdtree", "numba", "open3d"):
        emit("info", name, metadata.version(name) if try_import(name) else "not installed")
    omp = os.environ.get("OMP_NUM_THREADS", f"{os.cpu_count()} (default)")
    emit("info", "peer threads", f"numba 1 (serial njit); open3d and pykdtree OpenMP {omp}; cKDTree workers=-1")


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    np = try_import("numpy")
    if np is None:  # the Rust side shows every peer as "n/a (not installed)"
        emit("info", "numpy", "not installed: no Python peer can run")
        return
    numba = try_import("numba")
    o3d = try_import("open3d")
    x = Inputs(sys.argv[1], np)
    info(np, numba, o3d)
    bench_backproject(np, o3d, x)
    bench_zbuffer(np, numba, o3d, x)
    bench_voxel(np, o3d, x)
    bench_overlap(np, x)
    bench_overlap_open3d(np, o3d, x)


if __name__ == "__main__":
    main()
