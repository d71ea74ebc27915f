#!/usr/bin/env python
"""Benchmark writing the paper's full bed as ParaView files: meshio's .vtu against amfe 0.2's .vtp.

    source run/env.sh && .venv/bin/python -m run.bench.vtu [--dir DIR] [--repeat 3]
        [--cases 6] [--baseline-ref 0e6b870]

The bed is the paper's (`amfe pack --size 3 3 0.3 --seed 1`: 295 583 particles,
1 702 008 bonds), made once in DIR. The fields are synthetic, of the shapes a
solve gives (no solve: it would take minutes and changes nothing in the
writing): normal random displacements, rotations and bond loads, the bed's
own centres, radii, bonds and a*. Every value is random in all 52 bits, as a
solve's are, so compression sees what it would on real files.

The baseline is amfe 0.2's writer (amfe/io/vtp.py and amfe/io/vtkxml.py),
taken from git at --baseline-ref (the last commit of main that had it) into a
temporary module, and timed in the same run, interleaved with the new writer
(amfe.io.vtu.write_fields_vtu, stored) and with meshio's zlib (the same writer
with COMPRESSION = "zlib"), --repeat times each. Prints the minimum and median
seconds of each writer, the ratios to the baseline (target: the stored .vtu
at most 1.5 x the .vtp), and the file sizes.
"""
import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from run.common import ROOT, parser  # noqa: E402
TARGET = 1.5


def baseline_writer(ref, tmp):
    """amfe 0.2's write_fields_vtp, loaded from git ``ref`` as a module of its own."""
    for name in ("vtkxml", "vtp"):
        text = subprocess.run(["git", "show", f"{ref}:amfe/io/{name}.py"], cwd=ROOT, check=True,
                              capture_output=True, text=True).stdout
        text = text.replace("from amfe.io.vtkxml import", "from old_vtkxml import")
        with open(os.path.join(tmp, f"old_{name}.py"), "w") as fh:
            fh.write(text)
    import importlib.util
    for name in ("old_vtkxml", "old_vtp"):   # old_vtp imports old_vtkxml: load that first
        spec = importlib.util.spec_from_file_location(name, os.path.join(tmp, f"{name}.py"))
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules["old_vtp"].write_fields_vtp


def synthetic_fields(bed_path, k):
    """Fields of the shapes a solve of ``bed_path`` gives: the bed's geometry, random values."""
    import amfe
    from amfe.io.fields import Fields
    from amfe.model.bonds import find_bonds
    from amfe.vocab import CASE_NAMES

    bed = amfe.read_bed(bed_path)
    b = find_bonds(bed.centers, bed.radii)
    n, m = bed.n, len(b.i)
    rng = np.random.default_rng(1)

    def normal(*shape, scale=1.0):
        return rng.standard_normal(shape) * scale

    return Fields(particle_id=np.arange(n, dtype=np.int64), centers=bed.centers, radii=bed.radii,
                  bonds=np.stack([b.i, b.j], axis=1).astype(np.int64), a_star=b.a_star,
                  boundary=rng.random((k, n)) < 0.05,
                  macro_strain=np.array([np.diag([1.0, 0, 0])] * k),
                  displacement=normal(k, n, 3, scale=1e-4), rotation=normal(k, n, 3),
                  force=normal(k, m, 3, scale=10), moment=normal(k, m, 3, scale=1e-4),
                  axial_force=normal(k, m, scale=10), shear_force=np.abs(normal(k, m)),
                  torsion=normal(k, m, scale=1e-5), bending_moment=np.abs(normal(k, m)),
                  case_names=tuple(CASE_NAMES[:k]))


def timed_write(write, fields, parent):
    """(seconds, [case file sizes in bytes]) of one set written into a fresh directory."""
    out = tempfile.mkdtemp(dir=parent)
    try:
        t0 = time.perf_counter()
        paths = write(out, fields)
        seconds = time.perf_counter() - t0
        return seconds, [os.path.getsize(p) for p in paths[:-1]]
    finally:
        shutil.rmtree(out)


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--dir", default="results/bench_vtu", help="work directory (the bed, files)")
    ap.add_argument("--repeat", type=int, default=3, help="sets written by each writer")
    ap.add_argument("--cases", type=int, default=6, help="load cases per set")
    ap.add_argument("--baseline-ref", default="0e6b870",
                    help="git commit whose amfe/io/vtp.py is the baseline (amfe 0.2)")
    args = ap.parse_args(argv)
    from amfe.io import vtu

    os.makedirs(args.dir, exist_ok=True)
    bed = os.path.join(args.dir, "bed.h5")
    if not os.path.exists(bed):
        subprocess.run([sys.executable, "-m", "amfe.cli", "pack", "-o", bed, "--size", "3", "3",
                        "0.3", "--seed", "1"], check=True, capture_output=True)
    fields = synthetic_fields(bed, args.cases)
    print(f"bed {bed}: {len(fields.particle_id)} particles, {len(fields.bonds)} bonds, "
          f"{args.cases} cases (synthetic fields)", flush=True)

    def zlib_vtu(out, f):
        vtu.COMPRESSION = "zlib"
        try:
            return vtu.write_fields_vtu(out, f)
        finally:
            vtu.COMPRESSION = None

    with tempfile.TemporaryDirectory() as tmp:
        writers = {f".vtp (amfe 0.2, {args.baseline_ref})": baseline_writer(args.baseline_ref,
                                                                               tmp),
                   ".vtu meshio, stored": vtu.write_fields_vtu,
                   ".vtu meshio, zlib": zlib_vtu}
        times = {name: [] for name in writers}
        sizes = {}
        for r in range(args.repeat):            # interleaved: the load falls on all alike
            for name, write in writers.items():
                seconds, sizes[name] = timed_write(write, fields, args.dir)
                times[name].append(seconds)
                print(f"  round {r + 1}: {name}: {seconds:.2f} s (load "
                      f"{os.getloadavg()[0]:.1f})", flush=True)
    base = list(writers)[0]
    b_min, b_med = min(times[base]), statistics.median(times[base])
    print(f"\n{'writer':<32}{'min s':>7}{'median s':>9}{'x .vtp':>8}{'MB/case':>9}{'MB/set':>8}")
    for name in writers:
        t_min, t_med = min(times[name]), statistics.median(times[name])
        print(f"{name:<32}{t_min:7.2f}{t_med:9.2f}{t_med / b_med:8.2f}"
              f"{np.mean(sizes[name]) / 1e6:9.1f}{sum(sizes[name]) / 1e6:8.0f}")
    stored = ".vtu meshio, stored"
    ratio = statistics.median(times[stored]) / b_med
    print(f"\nstored .vtu / .vtp (median): {ratio:.2f} (target <= {TARGET}); min/min: "
          f"{min(times[stored]) / b_min:.2f}; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores")
    return 0 if ratio <= TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
