#!/usr/bin/env python3
"""Where the true place ranked among the whole-map candidates of each search of a run.

Usage: coarse_ranks.py DATASET RUN.log

RUN.log is the stderr of `jointloc run --sequential --dataset DATASET --out OUT
--log "jointloc_absloc::localizer=trace,jointloc_system=debug"`. For every whole-map search
it prints the rank of the first candidate within 8 m of the ground point under the camera
(`uav/gt.txt`, the optical axis meeting the ground 10 m below), the best fine correlation
there, and what the search returned (fix or placement below the gate, and its error).
Standard library only.
"""
import math
import re
import sys

NUM = r"=([-\d.e]+)"


def ground_points(dataset):
    gt = {}
    for line in open(f"{dataset}/uav/gt.txt"):
        if line.startswith("#") or not line.strip():
            continue
        v = list(map(float, line.split()))
        x, y, _, qx, qy, qz, qw = v[1:8]
        ax = 2 * (qx * qz + qw * qy)
        ay = 2 * (qy * qz - qw * qx)
        az = 1 - 2 * (qx * qx + qy * qy)
        s = -10.0 / az
        gt[round(v[0] * 1e3)] = (x + s * ax, y + s * ay)
    return gt


def field(name, line):
    m = re.search(r"\b" + name + NUM, line)
    return float(m.group(1)) if m else None


def main(dataset, log):
    gt = ground_points(dataset)
    rows, cur = [], None
    for line in open(log):
        line = re.sub(r"\x1b\[[0-9;]*m", "", line)
        if "absolute localisation request" in line:
            if cur:
                rows.append(cur)
            t = field("timestamp", line)
            cur = {"t": t, "g": gt[round(t * 1e3)], "coarse": [], "fine": [], "res": None}
        elif cur is None:
            continue
        elif "whole-map coarse candidate" in line:
            cur["coarse"].append((field("x", line), field("y", line)))
        elif "whole-map seed refined" in line:
            cur["fine"].append((field("x", line), field("y", line), field("score", line)))
        elif "below the confidence gate" in line:
            cur["res"] = ("below gate", field("x", line), field("y", line), field("confidence", line))
        elif "virtual frame fix" in line:
            m = re.search(r"position=\[([-\d.e]+), ([-\d.e]+)", line)
            cur["res"] = ("fix", float(m.group(1)), float(m.group(2)), field("fix.confidence", line))
    if cur:
        rows.append(cur)
    searches = found = first = 0
    for r in rows:
        if not r["coarse"]:
            continue
        gx, gy = r["g"]
        d = [math.hypot(x - gx, y - gy) for x, y in r["coarse"]]
        rank = next((i for i, x in enumerate(d) if x < 8), None)
        near = [s for x, y, s in r["fine"] if math.hypot(x - gx, y - gy) < 3]
        res = r["res"]
        out = "" if not res else f"{res[0]}, {math.hypot(res[1] - gx, res[2] - gy):.1f} m off, w {res[3]:.3f}"
        print(f"t {r['t']:6.1f} s: true place rank {rank}, fine score there {max(near) if near else '-'} | {out}")
        searches += 1
        found += rank is not None
        first += rank == 0
    print(f"{searches} whole-map searches: true place among the candidates in {found}, first in {first}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
