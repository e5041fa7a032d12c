"""Prints the benchmark table of docs/status.md from a committed `jointloc bench` report.

Usage: python3 docs/benchmarks/readme_rows.py docs/benchmarks/<run>/report.md

Every cell is copied verbatim from the report's Table VI (APE rmse in metres, mean ± std over
seeds; JointLoc rate in Hz), so those numbers are never typed by hand.
"""

import sys

md = open(sys.argv[1], encoding="utf-8").read()
start = md.index("## 2. Visual localisation")
end = md.index("## 3.", start) if "## 3." in md[start:] else len(md)
rows = {}
for line in md[start:end].splitlines():
    if not line.startswith("| ") or line.startswith("| terrain") or line.startswith("|---"):
        continue
    c = [x.strip() for x in line.split("|")[1:-1]]
    terrain, difficulty, method, rmse, hz = c[0], c[1], c[2], c[5], c[8]
    kind = (
        "realtime" if "real time" in method
        else "final" if "as known at the end" in method
        else "jointloc" if method.startswith("JointLoc")
        else "vo" if method.startswith("VO")
        else "abs"
    )
    rows.setdefault((terrain, difficulty), {})[kind] = (rmse, hz)

print("| flights | JointLoc, sequential | JointLoc, as known at the end | JointLoc, real time | VO only, Sim(3)-aligned | absolute only, 2-D | JointLoc Hz (sequential / real time) |")
print("|---|---|---|---|---|---|---|")
for (terrain, difficulty), r in rows.items():
    get = lambda k, i: r.get(k, ("-", "-"))[i]
    print(
        f"| {terrain} {difficulty} | {get('jointloc', 0)} | {get('final', 0)} | {get('realtime', 0)} | "
        f"{get('vo', 0)} | {get('abs', 0)} | {get('jointloc', 1)} / {get('realtime', 1)} |"
    )
