#!/usr/bin/env python3
"""The VO trajectory put into the world frame by the absolute fixes alone: what a user
without ground truth gets from `jointloc vo` and a fix source, against `jointloc eval --align
sim3` (aligned to the ground truth, with hindsight).

Usage: vo_by_fixes.py DATASET VO.tum FIXES

VO.tum: `jointloc vo --out` (SLAM frame). FIXES: a `jointloc run` output's `fixes.txt` (its
used fixes). One similarity is fitted (Umeyama) from the VO's ground points under the optical
axis at the altimeter range (`DATASET/uav/altimeter.txt`, in SLAM units through the fitted
scale, iterated) to the fixes' ground points; fixes whose residual exceeds 3 × the median +
5 cm are dropped and the fit repeated. Prints the world-frame APE rmse of every VO pose
against `DATASET/uav/gt.txt`. Needs numpy; uses `../ape_breakdown.py` (Umeyama, quaternions)
and `../2026-12-05-coarse-first/fix_errors.py` (the file reader).
"""
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.join(HERE, ".."), os.path.join(HERE, "..", "2026-12-05-coarse-first")]
from ape_breakdown import quat_to_matrix, umeyama  # noqa: E402
from fix_errors import rows  # noqa: E402


def poses(path):
    return {round(v[0] * 1e3): np.array(v[1:8]) for v in rows(path)}


def main(dataset, vo_path, fixes_path):
    gt, vo = poses(f"{dataset}/uav/gt.txt"), poses(vo_path)
    alt = {round(v[0] * 1e3): v[1] for v in rows(f"{dataset}/uav/altimeter.txt")}
    # columns: t x y z qx qy qz qw confidence tile ssim match_score inliers used ...
    fixes = [v for v in rows(fixes_path) if v[13] > 0 and round(v[0] * 1e3) in vo]
    keys = [round(v[0] * 1e3) for v in fixes]
    ranges = np.array([alt[k] for k in keys])
    ground = np.array([[v[1], v[2], v[3] - alt[round(v[0] * 1e3)]] for v in fixes])
    centres = np.array([vo[k][:3] for k in keys])
    axes = np.array([quat_to_matrix(vo[k][3:])[:, 2] for k in keys])
    s, r, t = umeyama(centres, ground + np.array([0.0, 0.0, 1.0]) * ranges[:, None])
    for _ in range(5):
        src = centres + axes * (ranges / s)[:, None]
        s, r, t = umeyama(src, ground)
    residual = np.linalg.norm((s * (r @ src.T)).T + t - ground, axis=1)
    keep = residual < 3 * np.median(residual) + 0.05
    s, r, t = umeyama(src[keep], ground[keep])
    errors = np.array([s * r @ vo[k][:3] + t - gt[k][:3] for k in vo if k in gt])
    print(f"APE rmse {np.sqrt((errors**2).sum(1).mean()):.4f} m over {len(errors)} poses, "
          f"{keep.sum()} of {len(keep)} fixes")


if __name__ == "__main__":
    main(*sys.argv[1:4])
