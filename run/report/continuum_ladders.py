"""Issue 47's continuum labels, first pass: voxel ladders of many small beds, one JSON each.

Bed k of a plan (seed S) is a pure function of (S, k): a `tiny`-scale box (0.15 x 0.15 x
0.1 mm) or the figure-2 box (0.25 x 0.25 x 0.1 mm), every second bed, with the scan path,
enlargement and skipped pieces drawn so that the solid fraction spans about 0.2-0.8
(amfe.model.scales' small distribution at those boxes). Each bed runs
run/report/voxel_ladder.py (KUBC, the frame beside it, H = R/3, R/4, R/5 by default) on one
rank, and its record (the bed's parameters, the ladder, the extrapolated constants with
their GCI error, the frame's constants) is written atomically to OUT/bed_<k>.json: a kill
loses only the bed in flight, and the same command resumes. Beds whose necks the grid
cannot resolve are recorded with the reason. Every fifth bed (k % 5 == 4) is held out of
any fit.

    .venv/bin/python -m run.report.continuum_ladders -o OUT --count 200 [--seed 47001]
    (one process a core: add --every 2 0 to one and --every 2 1 to the other)
"""
import json
import os
import subprocess
import sys
import tempfile
import time

from amfe.errors import AmfeError
from amfe.io.atomic import write_json
from amfe.io.bedfile import write_bed
from amfe.model.bed import generate_bed
from amfe.model.scales import sample_bed_params
from run.common import ROOT, parser

BOXES = {"tiny": (0.15e-3, 0.15e-3, 0.1e-3), "figure2": (0.25e-3, 0.25e-3, 0.1e-3)}


def bed_of(seed, k):
    """(Bed, record of its parameters): bed k of the plan."""
    family = "tiny" if k % 2 == 0 else "figure2"
    params = sample_bed_params("small", seed * 100_000 + k)
    params["size"] = BOXES[family]
    bed = generate_bed(**params)
    return bed, {"family": family, "bed_seed": seed * 100_000 + k,
                 "held_out": k % 5 == 4, "n_particles": int(bed.n)}


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--count", type=int, default=200)
    ap.add_argument("--seed", type=int, default=47001)
    ap.add_argument("--levels", type=float, nargs="+", default=[3, 4, 5])
    ap.add_argument("--every", type=int, nargs=2, default=(1, 0), metavar=("N", "R"),
                    help="only the beds k with k %% N == R (one process a core: N 2, R 0 and 1)")
    args = ap.parse_args(argv)
    os.makedirs(args.output, exist_ok=True)
    for k in range(args.count):
        out = os.path.join(args.output, f"bed_{k:05d}.json")
        if os.path.exists(out) or k % args.every[0] != args.every[1]:
            continue
        t = time.perf_counter()
        try:
            bed, record = bed_of(args.seed, k)
        except AmfeError as exc:   # the plan's scan path left no bed: recorded, not a crash
            write_json(out, {"family": "tiny" if k % 2 == 0 else "figure2",
                             "bed_seed": args.seed * 100_000 + k, "held_out": k % 5 == 4,
                             "n_particles": 0, "error": [str(exc)],
                             "seconds": time.perf_counter() - t})
            print(f"bed {k}: no bed ({exc})", flush=True)
            continue
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "bed.h5")
            write_bed(path, bed)
            ladder = os.path.join(tmp, "ladder.json")
            proc = subprocess.run([sys.executable, "-m", "run.report.voxel_ladder", path,
                                   "--bc", "kubc", "--ranks", "1", "--frame", "--levels",
                                   *map(str, args.levels), "-o", ladder],
                                  cwd=ROOT, capture_output=True, text=True)
            if proc.returncode == 0:
                with open(ladder) as f:
                    record["ladder"] = json.load(f)
            else:
                record["error"] = (proc.stderr or proc.stdout).strip().splitlines()[-1:]
        record["seconds"] = time.perf_counter() - t
        write_json(out, record)
        print(f"bed {k}: {record['family']} {record['n_particles']} particles, "
              f"{'ok' if 'ladder' in record else record['error']}, {record['seconds']:.1f} s",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
