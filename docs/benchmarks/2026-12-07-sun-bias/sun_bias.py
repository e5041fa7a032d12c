#!/usr/bin/env python3
"""The fixes' common bias of a run against the two suns' shadow model.

Usage: sun_bias.py DATASET:RUN_OUT [DATASET:RUN_OUT ...]

For each run (a `jointloc run` output folder of a simulated dataset), the median over its
fixes of (fix x, y) minus the true ground point under the image centre (a ray of the true
pose through the image centre, at the altimeter's range), and its fit to
`c * (L_f u_f - L_m u_m)`: u the unit vector towards a sun's azimuth (x east, y north;
azimuth clockwise from north), L = 1 / tan(elevation) the length of a unit-height shadow,
f the flight's sun and m the map's (`[scene.uav_sun]`, `[scene.satellite_sun]` of
`map.toml`). Prints the bias, the angle between it and the model's direction, the fitted
c (metres per unit of the model) and the residual's share of the bias.
Needs numpy (`python3 -m venv v && v/bin/pip install numpy`).
"""
import math
import re
import sys

import numpy as np


def load(path):
    rows = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        v = [float(x) for x in line.split()]
        rows[round(v[0], 4)] = v[1:]
    return rows


def optical_axis(q):
    x, y, z, w = q
    return np.array((2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)))


def sun(map_toml, key):
    text = open(map_toml).read()
    m = re.search(
        r"\[scene\." + key + r"\]\s*azimuth_deg = ([-0-9.e]+)\s*elevation_deg = ([-0-9.e]+)",
        text,
    )
    return float(m.group(1)), float(m.group(2))


def towards(azimuth_deg):
    a = math.radians(azimuth_deg)
    return np.array((math.sin(a), math.cos(a)))


def main():
    for arg in sys.argv[1:]:
        dataset, run = arg.split(":")
        gt = load(f"{dataset}/uav/gt.txt")
        alt = load(f"{dataset}/uav/altimeter.txt")
        fixes = load(f"{run}/fixes.txt")
        errors = []
        for t, f in fixes.items():
            if t not in gt or t not in alt:
                continue
            g = gt[t]
            axis = optical_axis(g[3:7])
            centre = np.array(g[0:3])
            ground = centre + axis * (alt[t][0] / abs(axis[2]))
            errors.append(np.array(f[:2]) - ground[:2])
        if len(errors) < 10:
            print(f"{dataset}: {len(errors)} fixes, too few")
            continue
        b = np.median(np.array(errors), axis=0)
        fa, fe = sun(f"{dataset}/map.toml", "uav_sun")
        ma, me = sun(f"{dataset}/map.toml", "satellite_sun")
        v = towards(fa) / math.tan(math.radians(fe)) - towards(ma) / math.tan(math.radians(me))
        c = b.dot(v) / v.dot(v)
        residual = np.linalg.norm(b - c * v) / np.linalg.norm(b)
        angle = math.degrees(math.atan2(b[1], b[0]) - math.atan2(v[1], v[0]))
        angle = (angle + 180) % 360 - 180
        print(
            f"{dataset}: {len(errors)} fixes, suns flight ({fa:.0f}, {fe:.0f}) map ({ma:.0f}, "
            f"{me:.0f}), bias ({b[0]:+.3f}, {b[1]:+.3f}) |{np.linalg.norm(b):.3f}| m, "
            f"angle to the model {angle:+.1f} deg, c {c:+.3f} m, residual {100 * residual:.0f} %"
        )


if __name__ == "__main__":
    main()
