"""Open3D 0.19 as the peer of pointreggpt's registration core (tests/registration.rs).

  features DIR R_NORMAL NN_NORMAL R_FPFH NN_FPFH
      reads DIR/points.f32 (N x 3) and DIR/normals_ours.f32 (N x 3); writes DIR/normals_o3d.f32 (Open3D's
      estimate_normals with a hybrid search, oriented towards the camera at the origin) and DIR/fpfh_o3d.f32
      (N x 33: compute_fpfh_feature on the same points with OUR normals, so the histograms compare alone).

  rr BENCH BENCHMARK VOXEL SAMPLES DISTANCE ITERATIONS
      runs Open3D's own pipeline on every pair of BENCH/metadata/benchmarks/BENCHMARK/*/gt.log (voxel_down_sample,
      normals r=2*voxel max_nn 30, FPFH r=5*voxel max_nn 100, SAMPLES random points per cloud, then
      registration_ransac_based_on_feature_matching with the edge-length 0.9 and distance checkers) and scores each
      estimate with the official error (numpy, written here from the protocol's definition). Prints
      `pair <scene> <i> <j> <0|1>` per pair (registered or not), then `pairs <n>`, `registered <k>`, `seconds <t>`.
"""
import glob
import os
import sys
import time

import numpy as np
import open3d as o3d


def features(d, r_n, nn_n, r_f, nn_f):
    pts = np.fromfile(os.path.join(d, "points.f32"), dtype=np.float32).reshape(-1, 3).astype(np.float64)
    ours = np.fromfile(os.path.join(d, "normals_ours.f32"), dtype=np.float32).reshape(-1, 3).astype(np.float64)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=r_n, max_nn=nn_n))
    pcd.orient_normals_towards_camera_location(np.zeros(3))
    np.asarray(pcd.normals, dtype=np.float32).tofile(os.path.join(d, "normals_o3d.f32"))
    pcd.normals = o3d.utility.Vector3dVector(ours)
    f = o3d.pipelines.registration.compute_fpfh_feature(pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=r_f, max_nn=nn_f))
    np.asarray(f.data, dtype=np.float32).T.copy().tofile(os.path.join(d, "fpfh_o3d.f32"))


def read_records(path, rows):
    lines = [l.split() for l in open(path) if l.strip()]
    out = {}
    for k in range(0, len(lines), rows + 1):
        i, j = int(lines[k][0]), int(lines[k][1])
        out[(i, j)] = np.array([[float(x) for x in l] for l in lines[k + 1:k + 1 + rows]])
    return out


def quat_xyz(r):
    """x, y, z of the unit quaternion of rotation matrix r with w >= 0 (Shepperd's method)."""
    t = np.trace(r)
    if t > 0:
        s = np.sqrt(t + 1.0) * 2
        q = np.array([0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s])
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        q = np.array([(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s])
    elif r[1, 1] > r[2, 2]:
        s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        q = np.array([(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s])
    else:
        s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        q = np.array([(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s])
    return q[1:] if q[0] >= 0 else -q[1:]


def official_error(gt, est, info):
    d = np.linalg.inv(gt) @ est
    x = np.concatenate([d[:3, 3], quat_xyz(d[:3, :3])])
    return float(x @ info @ x / info[0, 0])


def describe(path, voxel, samples, rng):
    pcd = o3d.io.read_point_cloud(path).voxel_down_sample(voxel)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    pcd.orient_normals_towards_camera_location(np.zeros(3))
    f = o3d.pipelines.registration.compute_fpfh_feature(pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
    n = len(pcd.points)
    idx = np.sort(rng.choice(n, samples, replace=False)) if n > samples else np.arange(n)
    sel = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(pcd.points)[idx]))
    feat = o3d.pipelines.registration.Feature()
    feat.data = np.asarray(f.data)[:, idx]
    return sel, feat


def rr(bench, name, voxel, samples, distance, iterations):
    o3d.utility.random.seed(0)
    rng = np.random.default_rng(0)
    reg = o3d.pipelines.registration
    pairs = registered = 0
    seconds = 0.0
    for log in sorted(glob.glob(os.path.join(bench, "metadata/benchmarks", name, "*", "gt.log"))):
        scene = os.path.basename(os.path.dirname(log))
        gts = read_records(log, 4)
        infos = read_records(os.path.join(os.path.dirname(log), "gt.info"), 6)
        for (i, j), gt in gts.items():
            tgt, ft = describe(os.path.join(bench, scene, f"cloud_bin_{i}.ply"), voxel, samples, rng)
            src, fs = describe(os.path.join(bench, scene, f"cloud_bin_{j}.ply"), voxel, samples, rng)
            t0 = time.perf_counter()
            res = reg.registration_ransac_based_on_feature_matching(
                src, tgt, fs, ft, False, distance, reg.TransformationEstimationPointToPoint(False), 3,
                [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(distance)],
                reg.RANSACConvergenceCriteria(iterations, 0.999))
            seconds += time.perf_counter() - t0
            pairs += 1
            ok = official_error(gt, np.asarray(res.transformation), infos[(i, j)]) <= 0.2 ** 2
            registered += ok
            print(f"pair {scene} {i} {j} {int(ok)}")
    print(f"pairs {pairs}\nregistered {registered}\nseconds {seconds:.3f}")


if __name__ == "__main__":
    if sys.argv[1] == "features":
        features(sys.argv[2], float(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]), int(sys.argv[6]))
    elif sys.argv[1] == "rr":
        rr(sys.argv[2], sys.argv[3], float(sys.argv[4]), int(sys.argv[5]), float(sys.argv[6]), int(sys.argv[7]))
    else:
        sys.exit(f"unknown mode {sys.argv[1]}")
