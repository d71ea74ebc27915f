"""Issue 47's cost gate: `--springs continuum` against `--springs paper` on the paper's full bed.

Makes the paper's 3 x 3 x 0.3 mm bed once (`amfe pack`, seed 0), then runs
`mpirun -n N amfe homogenize BED --springs S` 2 x REPEATS times, alternating paper and
continuum, and prints per run the wall time, the CG iterations of the six cases and
the peak memory of the largest rank (ru_maxrss of the children: every rank is a child of
mpirun, the largest is what `getrusage(RUSAGE_CHILDREN)` reports), then the medians and
the ratios continuum / paper (the gate: iterations and memory at most 1.2x, time at most
1.1x).

    python -m run.bench.springs_cost [--ranks 2] [--repeats 3] [--out /tmp/amfe-springs-cost]
"""
import json
import os
import statistics
import subprocess
import sys
import time

from run.common import parser


def run(cmd):
    """(wall seconds, peak RSS of the largest child process [bytes]) of ``cmd`` in a fresh
    grandchild, so the peak is this command's alone."""
    probe = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
             "r = subprocess.run(sys.argv[1:]); w = time.perf_counter() - t; "
             "print(w, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024); "
             "sys.exit(r.returncode)")
    proc = subprocess.run([sys.executable, "-c", probe, *cmd], capture_output=True, text=True)
    if proc.returncode:
        sys.exit(f"failed: {' '.join(cmd)}\n{proc.stderr[-2000:]}")
    wall, rss = proc.stdout.split()[-2:]
    return float(wall), int(rss)


def main():
    ap = parser(__doc__)
    ap.add_argument("--ranks", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="/tmp/amfe-springs-cost")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    bed = os.path.join(args.out, "paper_bed.h5")
    amfe = [sys.executable, "-m", "amfe"]
    if not os.path.exists(bed):
        subprocess.run([*amfe, "pack", "-o", bed, "--size", "3", "3", "0.3", "--seed", "0"],
                       check=True, capture_output=True)
    rows = {"paper": [], "continuum": []}
    print(f"{'springs':10s} {'wall [s]':>9s} {'CG its':>7s} {'peak RSS [MB]':>14s}")
    for _ in range(args.repeats):
        for springs in ("paper", "continuum"):
            out = os.path.join(args.out, f"{springs}.json")
            wall, rss = run(["mpirun", "-n", str(args.ranks), *amfe, "homogenize", bed, "-o", out,
                             "--quiet", "--springs", springs])
            with open(out) as f:
                res = json.load(f)
            its = sum(res["solver"]["iterations"])
            rows[springs].append((wall, its, rss, res["properties"]["Ex"]))
            print(f"{springs:10s} {wall:9.2f} {its:7d} {rss / 1e6:14.0f}", flush=True)
    med = {k: [statistics.median(r[c] for r in v) for c in range(4)] for k, v in rows.items()}
    p, c = med["paper"], med["continuum"]
    print(f"medians of {args.repeats}: paper {p[0]:.2f} s, {p[1]:.0f} its, {p[2] / 1e6:.0f} MB; "
          f"continuum {c[0]:.2f} s, {c[1]:.0f} its, {c[2] / 1e6:.0f} MB")
    print(f"continuum / paper: time {c[0] / p[0]:.3f}, CG iterations {c[1] / p[1]:.3f}, "
          f"memory {c[2] / p[2]:.3f}; Ex {c[3] / 1e9:.1f} against {p[3] / 1e9:.1f} GPa "
          f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {args.ranks} ranks)")


if __name__ == "__main__":
    main()
