#!/usr/bin/env python3
"""Runs Open3D's point-to-point ICP on the inputs `infer`'s pinch example wrote and compares.

    cargo run --release -p infer --example pinch -- --out /tmp/pinch
    python3 scripts/icp_open3d.py /tmp/pinch        # needs `pip install open3d numpy`

Prints both results side by side and exits non-zero when fitness, inlier RMSE or the transform
disagree beyond the tolerances below. Not part of CI (Open3D is a large download).
"""
import json
import sys
import time
from pathlib import Path

import numpy as np
import open3d as o3d

FITNESS_TOL = 1e-3
RMSE_TOL_MM = 1e-3
TRANSLATION_TOL_MM = 1e-3
ROTATION_TOL = 1e-5  # max abs difference of rotation-matrix entries


def main() -> int:
    if len(sys.argv) != 2:
        print(__doc__)
        return 2
    folder = Path(sys.argv[1])
    ours = json.loads((folder / "icp.json").read_text())
    source = o3d.io.read_point_cloud(str(folder / "source.ply"))
    target = o3d.io.read_point_cloud(str(folder / "target.ply"))
    if len(source.points) == 0 or len(target.points) == 0:
        print(f"{folder}: empty point cloud", file=sys.stderr)
        return 1
    criteria = o3d.pipelines.registration.ICPConvergenceCriteria(
        relative_fitness=ours["relative_fitness"],
        relative_rmse=ours["relative_rmse"],
        max_iteration=ours["max_iterations"],
    )
    start = time.perf_counter()
    result = o3d.pipelines.registration.registration_icp(
        source,
        target,
        ours["max_correspondence_distance_mm"],
        np.array(ours["init"]),
        o3d.pipelines.registration.TransformationEstimationPointToPoint(),
        criteria,
    )
    seconds = time.perf_counter() - start
    theirs_t = np.asarray(result.transformation)
    ours_t = np.array(ours["transform"])
    rows = [
        ("fitness", ours["fitness"], result.fitness, FITNESS_TOL),
        ("inlier RMSE (mm)", ours["inlier_rmse_mm"], result.inlier_rmse, RMSE_TOL_MM),
    ]
    print(f"{len(source.points)} source points, {len(target.points)} target points")
    print(f"{'':18} {'ours':>12} {'Open3D':>12}")
    ok = True
    for name, a, b, tol in rows:
        good = abs(a - b) <= tol
        ok &= good
        print(f"{name:18} {a:12.6f} {b:12.6f} {'ok' if good else 'DIFFERENT'}")
    dt = np.abs(ours_t[:3, 3] - theirs_t[:3, 3]).max()
    dr = np.abs(ours_t[:3, :3] - theirs_t[:3, :3]).max()
    print(f"translation difference {dt:.2e} mm, rotation entries difference {dr:.2e}")
    print(f"iterations: ours {ours['iterations']} (Open3D does not report its count)")
    print(f"time: ours {ours['ms']:.1f} ms, Open3D {1e3 * seconds:.1f} ms (k-d tree build included in both)")
    ok &= dt <= TRANSLATION_TOL_MM and dr <= ROTATION_TOL
    print("agree" if ok else "DISAGREE")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
