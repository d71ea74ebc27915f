#!/usr/bin/env python
"""Benchmark `amfe view` on a 100 000-particle bed: pvpython (under xvfb-run) and matplotlib.

    source run/env.sh && .venv/bin/python -m run.bench.view [--dir DIR] [--ranks 2]
        [--size 1.75 1.75 0.3] [--case xx] [--skip-solve]

Makes the bed (`amfe pack --size 1.75 1.75 0.3`, 100 320 particles, 574 655
bonds), solves it with `amfe homogenize --vtu` under mpirun (timed, not part of
the target), then times `amfe view DIR --case xx` end to end, once with
`--backend paraview` and once with `--backend matplotlib`, each as a fresh
process (start-up, reading the 100 MB case file, rendering, writing the PNG).
Target: each under 30 s. --skip-solve reuses DIR's files. Prints wall and CPU
times (user + system of the child processes: on a shared machine the wall time
grows with the load, the CPU time does not), the PNG sizes, the case file's
size and the machine's load; and the time amfe takes to write the six case
files (from the arrays read back, so without a solve).
"""
import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

from run.common import ROOT, parser  # noqa: E402
AMFE = [sys.executable, "-m", "amfe.cli"]
TARGET_S = 30.0


def _children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def timed(cmd, **kw):
    """Run ``cmd``; returns (wall seconds, CPU seconds, stdout). Exits if it fails."""
    t0, c0 = time.perf_counter(), _children_cpu()
    proc = subprocess.run(cmd, capture_output=True, text=True, **kw)
    seconds, cpu = time.perf_counter() - t0, _children_cpu() - c0
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return seconds, cpu, proc.stdout


def time_write(vtu_dir):
    """Seconds to write the six case files of ``vtu_dir`` again (amfe.io.vtu), without a solve."""
    from amfe.io.fields import Fields
    from amfe.io.pvd import read_collection
    from amfe.io.vtu import read_case

    cases = [read_case(p) for _, p in read_collection(os.path.join(vtu_dir, "cases.pvd"))]
    first, k = cases[0], len(cases)
    pid = first["point_data"]["particle_id"]
    index = np.full(pid.max() + 1, -1)
    index[pid] = np.arange(pid.size)

    def stack(where, name):
        return np.array([c[where][name] for c in cases])

    f = Fields(particle_id=pid, centers=first["points"], radii=first["point_data"]["radius_m"],
               bonds=first["lines"], a_star=first["cell_data"]["a_star"],
               boundary=stack("point_data", "boundary").astype(bool),
               macro_strain=np.array([np.reshape(c["field_data"]["macro_strain"], (3, 3))
                                      for c in cases]),
               displacement=stack("point_data", "displacement_m"),
               rotation=stack("point_data", "rotation_rad"),
               force=stack("cell_data", "force_i_N"), moment=stack("cell_data", "moment_i_Nm"),
               axial_force=stack("cell_data", "axial_force_N"),
               shear_force=stack("cell_data", "shear_force_N"),
               torsion=stack("cell_data", "torsion_Nm"),
               bending_moment=stack("cell_data", "bending_moment_Nm"),
               case_names=tuple(c["field_data"]["case_name"] for c in cases))
    from amfe.io.vtu import write_fields_vtu
    with tempfile.TemporaryDirectory(dir=os.path.dirname(os.path.abspath(vtu_dir))) as tmp:
        t0 = time.perf_counter()
        write_fields_vtu(tmp, f)
        return time.perf_counter() - t0, k


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--dir", default="results/bench_view", help="work directory")
    ap.add_argument("--size", nargs=3, default=["1.75", "1.75", "0.3"], metavar="MM")
    ap.add_argument("--ranks", type=int, default=2, help="MPI ranks of the solve")
    ap.add_argument("--case", default="xx")
    ap.add_argument("--skip-solve", action="store_true", help="reuse DIR/vtu")
    args = ap.parse_args(argv)
    os.makedirs(args.dir, exist_ok=True)
    bed, vtu_dir = os.path.join(args.dir, "bed.h5"), os.path.join(args.dir, "vtu")
    if not args.skip_solve:
        t, _, _ = timed(AMFE + ["pack", "-o", bed, "--size", *args.size, "--seed", "0"])
        print(f"pack {' x '.join(args.size)} mm: {t:.1f} s", flush=True)
        t, _, out = timed(["mpirun", "-n", str(args.ranks)] + AMFE
                          + ["homogenize", bed, "-o", os.path.join(args.dir, "r.json"),
                             "--vtu", vtu_dir, "--quiet"], cwd=ROOT)
        print(out.splitlines()[0])
        print(f"homogenize --vtu on {args.ranks} ranks: {t:.1f} s (solve and files; load "
              f"{os.getloadavg()[0]:.1f})", flush=True)
    t, k = time_write(vtu_dir)
    print(f"writing the {k} case files (amfe.io.vtu.write_fields_vtu): {t:.1f} s", flush=True)
    case_file = os.path.join(vtu_dir, f"case_{args.case}.vtu")
    print(f"case file {case_file}: {os.path.getsize(case_file) / 1e6:.0f} MB")
    print(f"load average before the views: {os.getloadavg()[0]:.1f} "
          f"({os.cpu_count()} cores)")
    rows = []
    for backend in ("paraview", "matplotlib"):
        outdir = os.path.join(args.dir, f"png_{backend}")
        load = os.getloadavg()[0]
        t, cpu, out = timed(AMFE + ["view", vtu_dir, "--case", args.case, "-o", outdir,
                                    "--backend", backend])
        png = out.strip().splitlines()[-1].removeprefix("wrote ")
        rows.append((backend, t, cpu, load, os.path.getsize(png) / 1e3, png))
        print("\n".join(out.strip().splitlines()[:-1]), flush=True)
    print(f"\n{'backend':<12}{'wall s':>8}{'CPU s':>7}{'target':>8}{'load':>6}{'PNG kB':>8}  file")
    for backend, t, cpu, load, kb, png in rows:
        print(f"{backend:<12}{t:8.1f}{cpu:7.1f}{TARGET_S:8.0f}{load:6.1f}{kb:8.0f}  {png}"
              + ("" if t < TARGET_S else "  OVER TARGET"))
    return 0 if all(row[1] < TARGET_S for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
