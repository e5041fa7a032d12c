"""Runs OpenCV's ORB on the images listed in a job file and writes keypoints and descriptors
as JSON, for tests/orb_vs_opencv.rs (which computes every metric for both extractors with
the same Rust code).

usage: python orb_vs_opencv.py JOB.json OUT.json
JOB.json: {"images": [path, ...], "nfeatures": 1000, "scale_factor": 1.2, "nlevels": 8}
OUT.json: {"opencv": "4.x", "results": [{"keypoints": [[x, y, size, angle_deg, octave,
          response], ...], "descriptors": ["64 hex digits", ...], "seconds": t}, ...]}
"""

import json
import sys
import time

import cv2


def main() -> None:
    job_path, out_path = sys.argv[1], sys.argv[2]
    with open(job_path) as f:
        job = json.load(f)
    cv2.setNumThreads(1)
    orb = cv2.ORB_create(
        nfeatures=int(job["nfeatures"]),
        scaleFactor=float(job["scale_factor"]),
        nlevels=int(job["nlevels"]),
    )
    results = []
    for path in job["images"]:
        img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise SystemExit(f"cannot read {path}")
        t = time.perf_counter()
        kps, desc = orb.detectAndCompute(img, None)
        seconds = time.perf_counter() - t
        keypoints = [
            [k.pt[0], k.pt[1], k.size, k.angle, k.octave, k.response] for k in kps
        ]
        descriptors = [] if desc is None else [bytes(d).hex() for d in desc]
        results.append(
            {"keypoints": keypoints, "descriptors": descriptors, "seconds": seconds}
        )
    with open(out_path, "w") as f:
        json.dump({"opencv": cv2.__version__, "results": results}, f)


if __name__ == "__main__":
    main()
