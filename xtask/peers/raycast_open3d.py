"""Peer for `cargo xtask bench raycast`: Open3D's RaycastingScene (Embree) on the same triangles
and rays. Not part of CI. Needs: pip install open3d numpy.

Usage: python3 raycast_open3d.py SCENE.bin REPS THREADS
Prints build_s=, cast_s= (medians) and the largest depth difference against our caster.
"""
import sys
import time

import numpy as np
import open3d as o3d

R_MM, MAX_DEPTH_MM = 25.0, 9.4


def main():
    path, reps, threads = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    buf = open(path, "rb").read()
    off = 0
    n_tris = int.from_bytes(buf[off:off + 4], "little"); off += 4
    tris = np.frombuffer(buf, "<f4", n_tris * 9, off).reshape(-1, 3); off += n_tris * 36
    n_rays = int.from_bytes(buf[off:off + 4], "little"); off += 4
    dirs = np.frombuffer(buf, "<f4", n_rays * 3, off).reshape(-1, 3); off += n_rays * 12
    ours = np.frombuffer(buf, "<f4", n_rays, off)

    verts = np.ascontiguousarray(tris, dtype=np.float32)
    faces = np.arange(n_tris * 3, dtype=np.uint32).reshape(-1, 3)
    rays = np.zeros((n_rays, 6), np.float32)
    rays[:, 3:] = dirs
    rays = o3d.core.Tensor(rays)

    def build():
        scene = o3d.t.geometry.RaycastingScene(nthreads=threads)
        scene.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(faces))
        # Embree builds its BVH lazily: a one-ray cast commits the scene.
        scene.cast_rays(rays[:1], nthreads=threads)
        return scene

    builds, casts = [], []
    scene = build()
    scene.cast_rays(rays, nthreads=threads)
    for _ in range(reps):
        t = time.perf_counter(); scene = build(); builds.append(time.perf_counter() - t)
        t = time.perf_counter(); hits = scene.cast_rays(rays, nthreads=threads); casts.append(time.perf_counter() - t)
    t_hit = hits["t_hit"].numpy()
    depth = np.clip(R_MM - t_hit, 0.0, MAX_DEPTH_MM)
    depth[~np.isfinite(t_hit)] = 0.0
    print(f"build_s={np.median(builds):.6f} cast_s={np.median(casts):.6f} "
          f"max_abs_depth_diff_mm={np.abs(depth - ours).max():.3e}")


if __name__ == "__main__":
    main()
