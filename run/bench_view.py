#!/usr/bin/env python
"""Benchmark `amfe view` on a 100 000-particle bed: pvpython (under xvfb-run) and matplotlib.

    source run/env.sh && .venv/bin/python run/bench_view.py [--dir DIR] [--ranks 2]
        [--size 1.75 1.75 0.3] [--case xx] [--skip-solve]

Makes the bed (`amfe pack --size 1.75 1.75 0.3`, 100 320 particles, 574 655
bonds), solves it with `amfe homogenize --vtu` under mpirun (timed, not part of
the target), then times `amfe view DIR --case xx` end to end, once with
`--backend paraview` and once with `--backend matplotlib`, each as a fresh
process (start-up, reading the 80 MB case file, rendering, writing the PNG).
Target: each under 30 s. --skip-solve reuses DIR's files. Prints the times,
the PNG sizes, the case file's size and the machine's load.
"""
import argparse
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
AMFE = [sys.executable, "-m", "amfe.cli"]
TARGET_S = 30.0


def timed(cmd, **kw):
    """Run ``cmd``; returns (seconds, stdout). Exits with its status if it fails."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, **kw)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return seconds, proc.stdout


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", default="results/bench_view", help="work directory")
    ap.add_argument("--size", nargs=3, default=["1.75", "1.75", "0.3"], metavar="MM")
    ap.add_argument("--ranks", type=int, default=2, help="MPI ranks of the solve")
    ap.add_argument("--case", default="xx")
    ap.add_argument("--skip-solve", action="store_true", help="reuse DIR/vtp")
    args = ap.parse_args(argv)
    os.makedirs(args.dir, exist_ok=True)
    bed, vtp = os.path.join(args.dir, "bed.h5"), os.path.join(args.dir, "vtp")
    if not args.skip_solve:
        t, _ = timed(AMFE + ["pack", "-o", bed, "--size", *args.size, "--seed", "0"])
        print(f"pack {' x '.join(args.size)} mm: {t:.1f} s", flush=True)
        t, out = timed(["mpirun", "-n", str(args.ranks)] + AMFE
                       + ["homogenize", bed, "-o", os.path.join(args.dir, "r.json"),
                          "--vtu", vtp, "--quiet"], cwd=ROOT)
        print(out.splitlines()[0])
        print(f"homogenize --vtu on {args.ranks} ranks: {t:.1f} s (solve and files)", flush=True)
    case_file = os.path.join(vtp, f"case_{args.case}.vtp")
    print(f"case file {case_file}: {os.path.getsize(case_file) / 1e6:.0f} MB")
    print(f"load average before the views: {os.getloadavg()[0]:.1f} "
          f"({os.cpu_count()} cores)")
    rows = []
    for backend in ("paraview", "matplotlib"):
        outdir = os.path.join(args.dir, f"png_{backend}")
        t, out = timed(AMFE + ["view", vtp, "--case", args.case, "-o", outdir,
                               "--backend", backend])
        png = out.strip().splitlines()[-1].removeprefix("wrote ")
        rows.append((backend, t, os.path.getsize(png) / 1e3, png))
        print(out.strip().splitlines()[0], flush=True)
    print(f"\n{'backend':<12}{'seconds':>9}{'target':>8}{'PNG kB':>8}  file")
    for backend, t, kb, png in rows:
        print(f"{backend:<12}{t:9.1f}{TARGET_S:8.0f}{kb:8.0f}  {png}"
              + ("" if t < TARGET_S else "  OVER TARGET"))
    return 0 if all(t < TARGET_S for _, t, _, _ in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
