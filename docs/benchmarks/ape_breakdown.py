#!/usr/bin/env python3
"""Splits a trajectory's Sim(3)-aligned APE into frame-to-frame jitter and slow drift, and
tells whether the jitter is the tilt/shift ambiguity of a nadir camera.

    python3 ape_breakdown.py GT.tum EST.tum [--window 9] [--align sim3|none]

Both files are TUM (timestamp tx ty tz qx qy qz qw, camera-to-world); frames are paired by
timestamp. `--align none` compares world-frame outputs (JointLoc's) as they are. Printed: the
APE rmse; the high-frequency part of the position error (the
error minus its moving average over --window frames) per axis, the same for the rotation
error (mrad), and for the ground point under the camera (the camera position moved along the
rotation error by the mean height); and the correlation of the x (y) jitter with the rotation
error about y (x). A correlation near ±1 with a small ground-point jitter means the camera's
jitter is a tilt traded for a shift that keeps the ground where it is. Needs numpy.
"""
import argparse

import numpy as np


def load(path):
    rows = {}
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        v = line.split()
        rows[round(float(v[0]), 4)] = np.array([float(x) for x in v[1:8]])
    return rows


def umeyama(src, dst):
    """s, R, t with dst ≈ s R src + t (least squares)."""
    ms, md = src.mean(0), dst.mean(0)
    xs, xd = src - ms, dst - md
    u, d, vt = np.linalg.svd(xd.T @ xs / len(src))
    e = np.eye(3)
    if np.linalg.det(u @ vt) < 0:
        e[2, 2] = -1
    r = u @ e @ vt
    s = np.trace(np.diag(d) @ e) / ((xs**2).sum() / len(src))
    return s, r, md - s * r @ ms


def quat_to_matrix(q):
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def high_pass(a, k):
    smooth = np.array([a[max(0, j - k // 2): j + k // 2 + 1].mean(0) for j in range(len(a))])
    return a - smooth


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("gt")
    ap.add_argument("est")
    ap.add_argument("--window", type=int, default=9)
    ap.add_argument("--align", choices=["sim3", "none"], default="sim3")
    a = ap.parse_args()
    gt, est = load(a.gt), load(a.est)
    ts = sorted(set(gt) & set(est))
    if len(ts) < 3 * a.window:
        raise SystemExit(f"{a.est}: only {len(ts)} frames share a timestamp with {a.gt}")
    g = np.array([gt[t][:3] for t in ts])
    e = np.array([est[t][:3] for t in ts])
    s, r, t = umeyama(e, g) if a.align == "sim3" else (1.0, np.eye(3), np.zeros(3))
    err = (s * (r @ e.T)).T + t - g
    rot = []
    for stamp in ts:
        d = r @ quat_to_matrix(est[stamp][3:]) @ quat_to_matrix(gt[stamp][3:]).T
        rot.append(np.array([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]) / 2)
    rot = np.array(rot)
    height = g[:, 2].mean()
    hf, hr = high_pass(err, a.window), high_pass(rot, a.window)
    ground = hf + np.cross(hr, np.array([0.0, 0.0, -height]))
    rms = lambda x: np.sqrt((x**2).mean(0))
    print(f"frames {len(ts)}  alignment {a.align}, scale {s:.4f}  APE rmse {np.sqrt((err**2).sum(1).mean()):.4f} m")
    print(f"jitter (error minus its {a.window}-frame mean), rms x y z: camera {np.round(rms(hf), 4)} m, "
          f"ground point {np.round(rms(ground), 4)} m, rotation {np.round(1000 * rms(hr), 2)} mrad")
    print(f"jitter total {np.sqrt((hf**2).sum(1).mean()):.4f} m; drift (the rest) "
          f"{np.sqrt(max(0.0, (err**2).sum(1).mean() - (hf**2).sum(1).mean())):.4f} m")
    print(f"correlation x with rotation about y {np.corrcoef(hf[:, 0], hr[:, 1])[0, 1]:+.3f}, "
          f"y with rotation about x {np.corrcoef(hf[:, 1], hr[:, 0])[0, 1]:+.3f}")


if __name__ == "__main__":
    main()
