"""Issue 48's sweep gate: a 3 x 3 grid of hatch spacing and track width, 4 seeds, small beds.

Runs `amfe sweep` on N ranks with the solver, then with the surrogate alone, then with the
surrogate and --fallback, each in a fresh directory, and prints each one's wall time, the
surrogate's ratio to the solver (its start-up included, and per bed from the rows' own
seconds), how many beds the fallback solved, and the largest relative difference between
the solver's rows and `amfe homogenize` of three of the same beds on one rank.

    python run/bench/sweep.py [--ranks 2] [--out /tmp/amfe-bench-sweep]
"""
import csv
import json
import os
import shutil
import subprocess
import sys
import time
from decimal import Decimal

from run.common import ROOT, parser

GRID = ["--grid", "hatch_spacing=0.1,0.12,0.15", "--grid", "track_width=0.05,0.08,0.1",
        "--seeds", "4", "--no-progress"]
CONSTANTS = ["Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy"]


def amfe(args, ranks=None):
    cmd = [sys.executable, "-m", "amfe.cli", *args]
    if ranks:
        cmd = ["mpirun", "-n", str(ranks), *cmd]
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode:
        sys.exit(f"failed: {' '.join(cmd)}\n{proc.stderr}")
    return time.perf_counter() - t


def rows(directory):
    with open(os.path.join(directory, "beds.csv")) as f:
        return list(csv.DictReader(f))


def main():
    ap = parser(__doc__)
    ap.add_argument("--ranks", type=int, default=2)
    ap.add_argument("--out", default="/tmp/amfe-bench-sweep")
    args = ap.parse_args()
    shutil.rmtree(args.out, ignore_errors=True)
    # amfe's bytecode written first, as an installation has it after its first run (a
    # machine with PYTHONDONTWRITEBYTECODE set would compile edited modules in every process)
    subprocess.run([sys.executable, "-m", "compileall", "-q", *(os.path.join(ROOT, d) for d in
                    ("amfe", "solvers", "training"))], check=True, capture_output=True)
    runs = {}
    for name, extra in (("solver", []), ("surrogate", ["--method", "surrogate"]),
                        ("fallback", ["--method", "surrogate", "--fallback"])):
        d = os.path.join(args.out, name)
        runs[name] = (amfe(["sweep", "-o", d, *GRID, *extra], args.ranks), rows(d))
    t_solver, solved = runs["solver"]
    print(f"{'run':10s} {'wall [s]':>9s} {'rows [s]':>9s} {'/ solver':>9s} {'solved':>7s}")
    for name, (t, r) in runs.items():
        busy = sum(float(x["seconds [s]"]) for x in r)
        busy_solver = sum(float(x["seconds [s]"]) for x in solved)
        n_solved = sum(x["source"] == "solver" for x in r)
        print(f"{name:10s} {t:9.2f} {busy:9.2f} {t / t_solver:8.1%} {n_solved:7d}"
              f"   (rows: {busy / busy_solver:.1%} of the solver's)")
    worst = 0.0
    for k in (0, 17, 35):
        row = solved[k]
        bed = os.path.join(args.out, f"bed{k}.h5")
        mm = {k: str(Decimal(row[f"{k} [m]"]).scaleb(3)) for k in ("track_width", "hatch_spacing")}
        amfe(["pack", "-o", bed, "--size", "0.6", "0.6", "0.3", "--track-width",
              mm["track_width"], "--hatch-spacing", mm["hatch_spacing"], "--seed", row["seed"],
              "--skip-seed", row["seed"]])
        out = os.path.join(args.out, f"r{k}.json")
        amfe(["homogenize", bed, "-o", out, "--quiet"])
        with open(out) as f:
            props = json.load(f)["properties"]
        for c in CONSTANTS:
            unit = "Pa" if c[0] == "E" else "-"
            worst = max(worst, abs(float(row[f"{c} [{unit}]"]) - props[c]) / abs(props[c]))
    print(f"solver rows against amfe homogenize of beds 0, 17, 35 (1 rank): max relative "
          f"difference {worst:.1e}")


if __name__ == "__main__":
    main()
