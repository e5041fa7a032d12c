#!/usr/bin/env python3
"""Error of each fix of a run against the ground point it measures.

Usage: fix_errors.py DATASET RUN_OUT [N]

Prints, for the first N fixes of RUN_OUT/fixes.txt (all by default), the horizontal distance
to the ground point under the camera at that time (`DATASET/uav/gt.txt`, 10 m below along
the optical axis) and the fix's confidence, then how many lie within 1 m and their RMS.
Standard library only.
"""
import math
import sys

from coarse_ranks import ground_points


def main(dataset, out, n=None):
    gt = ground_points(dataset)
    errors = []
    for line in open(f"{out}/fixes.txt"):
        if line.startswith("#"):
            continue
        v = line.split()
        gx, gy = gt[round(float(v[0]) * 1e3)]
        e = math.hypot(float(v[1]) - gx, float(v[2]) - gy)
        errors.append(e)
        if n is None or len(errors) <= n:
            print(f"t {float(v[0]):6.1f} s: {e:8.2f} m off, w {float(v[8]):.3f}")
    near = [e for e in errors if e < 1.0]
    rms = math.sqrt(sum(e * e for e in near) / len(near)) if near else float("nan")
    print(f"{len(near)} of {len(errors)} fixes within 1 m ({rms:.3f} m rmse of those)")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else None)
