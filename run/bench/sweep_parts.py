"""Where a surrogate sweep's time goes: its imports, its beds, its predictions, its plot.

    python -m run.bench.sweep_parts [--beds 18]

Times, in one process, the pieces a rank of `amfe sweep --method surrogate` spends its
time on for issue 48's grid (run/bench/sweep.py: hatch spacing 0.1, 0.12, 0.15 mm x
track width 0.05, 0.08, 0.1 mm, seeds 0-3, `small` beds), ``--beds`` of them (18: a
rank's share of the 36 on 2 ranks): the imports (numpy and mpi4py; amfe's sweep
modules; the predict path), generating the beds (their bonds by the C bond finder,
as a sweep's ranks find them), the first prediction (the models' load), the others
(images, networks, flag, intervals), writing the rows, and matplotlib's import.
Numbers for docs/benchmarks.md, "Parameter sweeps"; the whole sweep's wall time against
the solver's is run/bench/sweep.py.
"""
import os
import sys
import tempfile
import time

from run.common import parser


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--beds", type=int, default=18, help="beds to make and predict (>= 3)")
    args = ap.parse_args(argv)
    n = max(3, args.beds)
    clock = time.perf_counter
    t = clock()
    import mpi4py.MPI  # noqa: F401
    import numpy  # noqa: F401
    t_mpi = clock() - t
    t = clock()
    import amfe.cli.homogenize  # noqa: F401
    import amfe.cli.sweep  # noqa: F401
    from amfe.study.run import bed_of
    from amfe.study.spec import SweepSpec
    t_amfe = clock() - t
    t = clock()
    from amfe.io.atomic import write_json
    from amfe.study.surrogate import predict_rows
    t_predict = clock() - t
    points = tuple({"hatch_spacing": h * 1e-3, "track_width": w * 1e-3}
                   for h in (0.1, 0.12, 0.15) for w in (0.05, 0.08, 0.1))
    spec = SweepSpec(points=points, seeds=(0, 1, 2, 3), method="surrogate")
    t = clock()
    beds = [bed_of(spec, k)[0] for k in range(n)]
    t_beds = clock() - t
    cache = {}
    t = clock()
    predict_rows(cache, beds[:2])
    t_first = clock() - t
    t = clock()
    rows = predict_rows(cache, beds[2:])
    t_rest = clock() - t
    with tempfile.TemporaryDirectory() as tmp:
        t = clock()
        for k, row in enumerate(rows):
            write_json(os.path.join(tmp, f"row_{k:06d}.json"), row)
        t_rows = clock() - t
    t = clock()
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
    from matplotlib.figure import Figure  # noqa: F401
    t_plot = clock() - t
    print(f"imports: numpy and mpi4py {t_mpi:.3f} s, amfe's sweep modules {t_amfe:.3f} s, "
          f"the predict path {t_predict:.3f} s, matplotlib's Figure {t_plot:.3f} s")
    print(f"{n} beds made: {t_beds:.3f} s ({1e3 * t_beds / n:.1f} ms a bed)")
    print(f"first 2 predicted (the models' load): {t_first:.3f} s; numba imported: "
          f"{'numba' in sys.modules}")
    print(f"{n - 2} more predicted: {t_rest:.3f} s ({1e3 * t_rest / (n - 2):.1f} ms a bed); "
          f"their rows written: {t_rows:.3f} s")
    print(f"torch imported: {'torch' in sys.modules}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
