#!/usr/bin/env python3
"""Error of each fix against the ground point it measures, at any altitude.

Usage: fix_errors.py DATASET FIXES

FIXES is a `jointloc absloc --out` file or a `jointloc run` output's `fixes.txt` (timestamp,
x, y first). The ground point is where the true optical axis (`DATASET/uav/gt.txt`) meets the
ground, the altimeter's range below the camera (`DATASET/uav/altimeter.txt`), as a fix
measures it. Prints how many fixes lie within 1 m and 5 m, their RMS within 1 m, and the
largest error. Standard library only.
"""
import math
import sys


def rows(path):
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        yield [float(x) for x in line.split()]


def ground_points(dataset):
    ranges = {round(v[0] * 1e3): v[1] for v in rows(f"{dataset}/uav/altimeter.txt")}
    gt = {}
    for v in rows(f"{dataset}/uav/gt.txt"):
        x, y, _, qx, qy, qz, qw = v[1:8]
        ax = 2 * (qx * qz + qw * qy)
        ay = 2 * (qy * qz - qw * qx)
        az = 1 - 2 * (qx * qx + qy * qy)
        key = round(v[0] * 1e3)
        s = -ranges.get(key, 10.0) / az
        gt[key] = (x + s * ax, y + s * ay)
    return gt


def main(dataset, fixes):
    gt = ground_points(dataset)
    errors = [math.hypot(v[1] - gt[round(v[0] * 1e3)][0], v[2] - gt[round(v[0] * 1e3)][1])
              for v in rows(fixes)]
    near = [e for e in errors if e < 1.0]
    rms = math.sqrt(sum(e * e for e in near) / len(near)) if near else float("nan")
    print(f"fixes {len(errors)}, within 1 m {len(near)}, within 5 m "
          f"{sum(e < 5.0 for e in errors)}, rms within 1 m {rms:.3f} m, "
          f"max {max(errors, default=float('nan')):.1f} m")


if __name__ == "__main__":
    main(*sys.argv[1:3])
