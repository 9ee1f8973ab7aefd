#!/usr/bin/env python3
"""Open3D peers of the TSDF benchmark (driven by benchmarks/tsdf.rs).

Usage: tsdf_peers.py DIR

DIR holds the exact inputs the Rust side used, as .npy files:
  real_depth.npy    uint16 (N, H, W)  7-Scenes depth in millimetres, 0 = no depth (65535 already 0)
  real_poses.npy    float64 (N, 4, 4) camera-to-world
  synth_depth.npy   uint16 (M, H, W)  synthetic noisy depth in millimetres
  synth_poses.npy   float64 (M, 4, 4) camera-to-world
  intrinsics.npy    float64 [fx, fy, cx, cy]
  configs.npy       float64 (C, 2)    [voxel size m, truncation m] per configuration
  params.npy        float64 [depth_max m, reps, weight_threshold]

For every configuration and peer it fuses the real frames `reps` times (a fresh volume each time)
and prints

  timing <TAB> config <TAB> peer <TAB> integrate ms/frame <TAB> points ms <TAB> mesh ms <TAB> points <TAB> triangles

with the medians over the runs (integration: the run's total / N; extraction: one call on the
run's volume). It then fuses the synthetic frames once and writes the extracted surface points to
DIR/synth_points_<config>_<peer key>.npy (float32 (P, 3)), which the Rust side scores against the
exact scene, and prints `points <TAB> config <TAB> peer <TAB> file`. A peer that fails prints
`timing <TAB> config <TAB> peer <TAB> n/a <TAB> reason`. Lines starting with `info` carry versions.
Inputs are converted to Open3D types before any timing.
"""

import os
import statistics
import sys
import time


def emit(*fields):
    print("\t".join(str(f) for f in fields), flush=True)


def clean(e):
    return f"{type(e).__name__}: {e}".replace("\t", " ").replace("\n", " ")


class Peer:
    """One Open3D TSDF implementation: make() a volume, integrate(volume, frame), extract."""

    def __init__(self, key, name, make, integrate, points, mesh):
        self.key, self.name = key, name
        self.make, self.integrate, self.points, self.mesh = make, integrate, points, mesh


def peers(o3d, np, k, depth_max, weight_threshold):
    o3c = o3d.core
    fx, fy, cx, cy = k
    cpu = o3c.Device("CPU:0")
    intrinsic_t = o3c.Tensor(np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), o3c.float64)

    def vbg(block_resolution):
        def make(voxel, trunc):
            grid = o3d.t.geometry.VoxelBlockGrid(
                attr_names=("tsdf", "weight"),
                attr_dtypes=(o3c.float32, o3c.float32),
                attr_channels=((1), (1)),
                voxel_size=voxel,
                block_resolution=block_resolution,
                block_count=100000,
                device=cpu,
            )
            return (grid, trunc / voxel)

        def integrate(vol, frame):
            grid, mult = vol
            depth, extrinsic = frame["tensor"]
            coords = grid.compute_unique_block_coordinates(depth, intrinsic_t, extrinsic, 1000.0, depth_max, mult)
            grid.integrate(coords, depth, intrinsic_t, extrinsic, 1000.0, depth_max, mult)

        def points(vol):
            return vol[0].extract_point_cloud(weight_threshold).point.positions.numpy()

        def mesh(vol):
            return len(vol[0].extract_triangle_mesh(weight_threshold).triangle.indices)

        return integrate, make, points, mesh

    def scalable():
        def make(voxel, trunc):
            return o3d.pipelines.integration.ScalableTSDFVolume(
                voxel_length=voxel, sdf_trunc=trunc, color_type=o3d.pipelines.integration.TSDFVolumeColorType.NoColor
            )

        def integrate(vol, frame):
            rgbd, extrinsic = frame["legacy"]
            vol.integrate(rgbd, frame["legacy_k"], extrinsic)

        def points(vol):
            return np.asarray(vol.extract_point_cloud().points, dtype=np.float32)

        def mesh(vol):
            return len(vol.extract_triangle_mesh().triangles)

        return integrate, make, points, mesh

    out = []
    for br in (16, 8):
        integrate, make, points, mesh = vbg(br)
        out.append(Peer(f"vbg{br}", f"open3d VoxelBlockGrid ({br}^3 blocks)", make, integrate, points, mesh))
    integrate, make, points, mesh = scalable()
    out.append(Peer("scalable", "open3d ScalableTSDFVolume", make, integrate, points, mesh))
    return out


def convert(o3d, np, depths, poses, k, depth_max):
    """Every frame as the types both APIs take, built before timing."""
    o3c = o3d.core
    h, w = depths.shape[1:]
    fx, fy, cx, cy = k
    legacy_k = o3d.camera.PinholeCameraIntrinsic(w, h, fx, fy, cx, cy)
    color = o3d.geometry.Image(np.zeros((h, w, 3), np.uint8))
    frames = []
    for depth, pose in zip(depths, poses):
        extrinsic = np.linalg.inv(pose)
        depth = np.ascontiguousarray(depth)
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            color, o3d.geometry.Image(depth), depth_scale=1000.0, depth_trunc=depth_max, convert_rgb_to_intensity=False
        )
        frames.append(
            {
                "tensor": (o3d.t.geometry.Image(o3c.Tensor(depth)), o3c.Tensor(extrinsic, o3c.float64)),
                "legacy": (rgbd, extrinsic),
                "legacy_k": legacy_k,
            }
        )
    return frames


def main():
    d = sys.argv[1]
    try:
        import numpy as np
        import open3d as o3d
    except Exception as e:  # noqa: BLE001 - ImportError, or a broken shared library
        emit("info", "failure", f"open3d does not import: {clean(e)}")
        return
    emit("info", "open3d", o3d.__version__)
    emit("info", "numpy", np.__version__)
    emit("info", "OMP_NUM_THREADS", os.environ.get("OMP_NUM_THREADS", "unset (all cores)"))
    load = lambda name: np.load(os.path.join(d, name))  # noqa: E731
    k = [float(v) for v in load("intrinsics.npy")]
    configs = load("configs.npy")
    depth_max, reps, weight_threshold = load("params.npy")
    reps, depth_max, weight_threshold = int(reps), float(depth_max), float(weight_threshold)
    real = convert(o3d, np, load("real_depth.npy"), load("real_poses.npy"), k, depth_max)
    synth = convert(o3d, np, load("synth_depth.npy"), load("synth_poses.npy"), k, depth_max)

    for ci, (voxel, trunc) in enumerate(configs):
        for peer in peers(o3d, np, k, depth_max, weight_threshold):
            try:
                integ, pts_ms, mesh_ms, n_pts, n_tri = [], [], [], 0, 0
                for _ in range(reps):
                    vol = peer.make(float(voxel), float(trunc))
                    t0 = time.perf_counter()
                    for frame in real:
                        peer.integrate(vol, frame)
                    integ.append((time.perf_counter() - t0) / len(real) * 1e3)
                    t0 = time.perf_counter()
                    n_pts = len(peer.points(vol))
                    pts_ms.append((time.perf_counter() - t0) * 1e3)
                    t0 = time.perf_counter()
                    n_tri = peer.mesh(vol)
                    mesh_ms.append((time.perf_counter() - t0) * 1e3)
                med = statistics.median
                emit("timing", ci, peer.name, f"{med(integ):.3f}", f"{med(pts_ms):.3f}", f"{med(mesh_ms):.3f}", n_pts, n_tri)
                vol = peer.make(float(voxel), float(trunc))
                for frame in synth:
                    peer.integrate(vol, frame)
                path = os.path.join(d, f"synth_points_{ci}_{peer.key}.npy")
                np.save(path, np.ascontiguousarray(peer.points(vol), dtype=np.float32))
                emit("points", ci, peer.name, path)
            except Exception as e:  # noqa: BLE001 - a broken peer must not hide the others
                emit("timing", ci, peer.name, "n/a", clean(e))


if __name__ == "__main__":
    main()
