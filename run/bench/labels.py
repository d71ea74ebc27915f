"""Label-table benchmark: rebuilding a data set from its labels against labelling it.

    python -m run.bench.labels                       # 100 small beds on 2 ranks
    python -m run.bench.labels --count 200 --resolve 20
    python -m run.bench.labels --data DATA.h5        # an existing data set (no labelling)

Makes (unless --data) a `small` data set with ``mpirun -n R amfe dataset``
(--solver auto, the labelling path), exports its label table
(``--export-labels``), rebuilds it with ``mpirun -n R amfe dataset
--from-labels`` and checks the rebuild against the original (every stored and
recomputed field bit for bit). Prints each step's wall time, records per
second, the rebuild's speed-up over labelling (same beds, same run), the
CPU seconds per record of the rebuild (time-sharing leaves them alone) and the
projected time for 40 000 records on R cores. ``--resolve N``: re-solves N
records of the table with GAMG at rtol 1e-10 and prints the largest relative
error of the nine constants (the label contract: under 1e-5). The machine may
be shared: the load average before each step is printed.
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import h5py
import numpy as np
from run.common import parser

ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
AMFE = [sys.executable, "-m", "amfe.cli"]
SAME = ("images", "bond_images", "labels", "C", "density", "index", "seed", "status", "reason",
        "n_particles", "n_removed", "n_bonds", "volume")


def step(name, cmd):
    """Run cmd; returns (wall seconds, child CPU seconds)."""
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=ENV)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        sys.exit(f"{name} failed: {proc.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    print(f"{name:10s} {wall:8.1f} s wall, {cpu:8.1f} s CPU (load before {load:.1f})", flush=True)
    return wall, cpu


def same_records(a, b):
    with h5py.File(a, "r") as f, h5py.File(b, "r") as g:
        bad = [k for k in SAME if f[k][()].tobytes() != g[k][()].tobytes()]
        bad += [f"params/{n}" for n in f["params"]
                if f["params"][n][()].tobytes() != g["params"][n][()].tobytes()]
    return bad


def resolve(table, n, tmp):
    """Largest relative error of the nine constants over n re-solved records of ``table``."""
    from amfe.model.averages import compliance_and_constants
    from amfe.vocab import CONSTANT_NAMES
    with h5py.File(table, "r") as f:
        ok = np.flatnonzero(f["status"][()] == 0)[:n]
        seeds, C = f["bed_seed"][()][ok], f["C"][()][ok]
    worst = 0.0
    for seed, c in zip(seeds, C):
        bed, res = os.path.join(tmp, f"bed{seed}.h5"), os.path.join(tmp, f"r{seed}.json")
        for cmd in (["pack", "--scale", "small", "--seed", str(seed), "-o", bed],
                    ["homogenize", bed, "--solver", "gamg", "--rtol", "1e-10", "-o", res]):
            proc = subprocess.run(AMFE + cmd, capture_output=True, text=True, env=ENV)
            if proc.returncode:
                sys.exit(proc.stderr)
        with open(res) as fh:
            tight = json.load(fh)["properties"]
        stored = compliance_and_constants(c)[1]
        worst = max(worst, max(abs(tight[k] - stored[k]) / abs(tight[k]) for k in CONSTANT_NAMES))
    return len(ok), worst


def main():
    ap = parser(__doc__)
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--ranks", type=int, default=2)
    ap.add_argument("--seed", type=int, default=9)
    ap.add_argument("--data", help="an existing small data set (skips the labelling)")
    ap.add_argument("--resolve", type=int, default=0, metavar="N")
    args = ap.parse_args()
    mpi = ["mpirun", "-n", str(args.ranks)]
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or os.path.join(tmp, "data.h5")
        label = None
        if not args.data:
            label = step("label", mpi + AMFE + ["dataset", "-o", data, "--count", str(args.count),
                                                "--seed", str(args.seed), "--scale", "small",
                                                "--no-progress"])
        with h5py.File(data, "r") as f:
            count = int(f.attrs["count"])
        table = os.path.join(tmp, "bench_labels.h5")
        export = step("export", AMFE + ["dataset", "--export-labels", data, "-o", table])
        out = os.path.join(tmp, "rebuilt.h5")
        rebuild = step("rebuild", mpi + AMFE + ["dataset", "--from-labels", table, "-o", out,
                                                "--no-progress"])
        bad = same_records(data, out)
        print(f"{count} records; table {os.path.getsize(table) / 1024:.0f} KiB "
              f"({os.path.getsize(table) / count:.0f} B a record); rebuild equals the data set "
              f"bit for bit: {'yes' if not bad else 'NO: ' + ', '.join(bad)}")
        rate = count / rebuild[0]
        print(f"rebuild: {rate:.2f} records/s on {args.ranks} ranks, {rebuild[1] / count:.3f} CPU s "
              f"a record; 40 000 records: {40000 / rate / 3600:.2f} h at this rate, "
              f"{40000 * rebuild[1] / count / args.ranks / 3600:.2f} h on {args.ranks} idle "
              f"cores (CPU time / cores); export {count / export[0]:.1f} records/s")
        if label:
            print(f"label: {count / label[0]:.2f} records/s; rebuild / label speed: "
                  f"{label[0] / rebuild[0]:.1f}x (wall), {label[1] / rebuild[1]:.1f}x (CPU)")
        if args.resolve:
            n, worst = resolve(table, args.resolve, tmp)
            print(f"re-solved {n} records at GAMG rtol 1e-10: largest relative error of the nine "
                  f"constants {worst:.2e} (contract 1e-5)")


if __name__ == "__main__":
    main()
