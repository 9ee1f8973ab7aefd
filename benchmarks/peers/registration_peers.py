"""Open3D 0.19 peer of benchmarks/registration.rs: times normals, FPFH and RANSAC on feature matching on the
inputs the Rust side wrote into DIR, and prints `op <TAB> median ms <TAB> note` lines.

usage: registration_peers.py DIR REPS
"""
import os
import sys
import time

import numpy as np
import open3d as o3d

d, reps = sys.argv[1], int(sys.argv[2])
reg = o3d.pipelines.registration
o3d.utility.random.seed(3)


def timed(f):
    f()
    ms = []
    for _ in range(reps):
        t = time.perf_counter()
        out = f()
        ms.append((time.perf_counter() - t) * 1e3)
    return float(np.median(ms)), out


clouds = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.load(os.path.join(d, f"cloud{k}.npy")))) for k in range(2)]
normals_ms = fpfh_ms = 0.0
for c in clouds:
    def normals(c=c):
        c.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.05, max_nn=30))
        c.orient_normals_towards_camera_location(np.zeros(3))
    ms, _ = timed(normals)
    normals_ms += ms
    ms, _ = timed(lambda c=c: reg.compute_fpfh_feature(c, o3d.geometry.KDTreeSearchParamHybrid(radius=0.125, max_nn=100)))
    fpfh_ms += ms
print(f"normals\t{normals_ms:.3f}\t")
print(f"fpfh\t{fpfh_ms:.3f}\t")

pts = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.load(os.path.join(d, f"sampled{k}.npy")))) for k in range(2)]
feats = []
for k in range(2):
    f = reg.Feature()
    f.data = np.load(os.path.join(d, f"features{k}.npy")).T.copy()
    feats.append(f)
for key, iters, conf in [("ransac_fixed", 10000, 1.0), ("ransac_protocol", 50000, 0.999)]:
    def run():
        return reg.registration_ransac_based_on_feature_matching(
            pts[0], pts[1], feats[0], feats[1], False, 0.05, reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(0.05)],
            reg.RANSACConvergenceCriteria(iters, conf))
    ms, res = timed(run)
    print(f"{key}\t{ms:.3f}\tfitness {res.fitness:.4f}, {len(res.correspondence_set)} inliers")
