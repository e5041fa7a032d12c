"""Gallery of `jointloc sim` datasets: each picture is a dataset's first UAV frame (left) and
the map under it (right), sampled over the frame's footprint in the frame's orientation (nadir
approximation: the small tilt is ignored), both 256 px.

    python3 -m venv .venv && .venv/bin/pip install pillow numpy
    .venv/bin/python docs/gallery/make_gallery.py OUT_DIR DATASET [DATASET ...]

Writes OUT_DIR/<dataset folder name>.png.
"""

import sys
from pathlib import Path

import numpy as np
from PIL import Image

Image.MAX_IMAGE_PIXELS = None
SIDE = 256


def read_map_toml(path):
    """The few keys needed: gsd_m (first) and the camera-independent image name."""
    gsd, image = None, None
    for line in path.read_text().splitlines():
        key, _, value = line.partition("=")
        key, value = key.strip(), value.strip()
        if key == "gsd_m" and gsd is None:
            gsd = float(value)
        if key == "image" and image is None:
            image = value.strip('"')
    return gsd, image


def first_pose(gt):
    """Camera centre and rotation (camera to world) of the first TUM line."""
    for line in gt.read_text().splitlines():
        if line and not line.startswith("#"):
            _, x, y, z, qx, qy, qz, qw = (float(v) for v in line.split()[:8])
            rotation = np.array(
                [
                    [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
                    [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
                    [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
                ]
            )
            return np.array([x, y, z]), rotation
    raise ValueError(f"{gt}: no pose")


def picture(ds):
    gsd, image = read_map_toml(ds / "map.toml")
    centre, rotation = first_pose(ds / "uav" / "gt.txt")
    altitude = next(
        float(line.split()[1])
        for line in (ds / "uav" / "altimeter.txt").read_text().splitlines()
        if line and not line.startswith("#")
    )
    frame = Image.open(sorted((ds / "uav" / "images").iterdir())[0]).convert("L")
    fx = 500.0
    for line in (ds / "camera.yaml").read_text().splitlines():
        if line.strip().startswith(("Camera.fx:", "Camera1.fx:")):
            fx = float(line.split(":")[1])
    footprint_m = altitude * frame.width / fx
    satellite = np.asarray(Image.open(ds / image).convert("L"))
    # Ground point under each output pixel: along the camera's x (right) and y (down) axes.
    t = ((np.arange(SIDE) + 0.5) / SIDE - 0.5) * footprint_m
    right, down = rotation[:2, 0], rotation[:2, 1]
    gx = centre[0] + t[None, :] * right[0] + t[:, None] * down[0]
    gy = centre[1] + t[None, :] * right[1] + t[:, None] * down[1]
    u = np.clip(np.rint(gx / gsd).astype(int), 0, satellite.shape[1] - 1)
    v = np.clip(np.rint(-gy / gsd).astype(int), 0, satellite.shape[0] - 1)
    crop = Image.fromarray(satellite[v, u])
    out = Image.new("L", (2 * SIDE + 8, SIDE), 0)
    out.paste(frame.resize((SIDE, SIDE), Image.BILINEAR), (0, 0))
    out.paste(crop, (SIDE + 8, 0))
    return out


def main():
    out_dir = Path(sys.argv[1])
    out_dir.mkdir(parents=True, exist_ok=True)
    for ds in map(Path, sys.argv[2:]):
        target = out_dir / f"{ds.name}.png"
        if target.exists():
            sys.exit(f"{target} exists: remove it first")
        picture(ds).save(target, optimize=True)
        print(target)


if __name__ == "__main__":
    main()
