"""Runs evo's own command-line code paths (evo_ape / evo_rpe) for a list of cases and dumps
their results as JSON, for the Rust parity test (evo_parity.rs).

Usage: python evo_parity.py CASES.json OUT.json
CASES.json: [{"name": str, "tool": "ape" | "rpe", "argv": [str, ...]}, ...]
Each case runs exactly what `evo_<tool> <argv...> --save_results X.zip` would run, in-process
(one interpreter for all cases instead of one per case), and reads the saved zip back.
"""

import importlib
import json
import os
import sys
import tempfile

os.environ.setdefault("MPLBACKEND", "Agg")

from evo.tools import file_interface  # noqa: E402


def run_case(tool, argv, zip_path):
    parser = importlib.import_module(f"evo.cli.{tool}_parser").parser()
    args = parser.parse_args(argv + ["--save_results", zip_path, "--no_warnings", "--silent"])
    importlib.import_module(f"evo.cli.{tool}").run(args)
    result = file_interface.load_res_file(zip_path)
    out = {
        "stats": {k: float(v) for k, v in result.stats.items()},
        "errors": [float(e) for e in result.np_arrays["error_array"]],
    }
    sim3 = result.np_arrays.get("alignment_transformation_sim3")
    if sim3 is not None:
        out["alignment"] = [[float(v) for v in row] for row in sim3]
    return out


def main():
    with open(sys.argv[1]) as f:
        cases = json.load(f)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for index, case in enumerate(cases):
            zip_path = os.path.join(tmp, f"case{index}.zip")
            results[case["name"]] = run_case(case["tool"], case["argv"], zip_path)
    with open(sys.argv[2], "w") as f:
        json.dump(results, f)


if __name__ == "__main__":
    main()
