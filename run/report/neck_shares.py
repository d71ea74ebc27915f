"""Are `small` beds' particles of the kind the continuum springs were fitted on (issue 47)?

The springs' fit range is a range of the bed's *mean* neck share (amfe warns outside
it); this compares the *per-particle* neck shares (amfe.model.continuum_springs.neck_share)
of `small` beds with those of the fit's plan (run/report/continuum_ladders.py), whose
tiny boxes have more particles on their faces. Pure numpy, about a minute.

    .venv/bin/python -m run.report.neck_shares [--small 12] [--plan-step 3]
"""
import numpy as np

from amfe.errors import AmfeError
from amfe.model.continuum_springs import neck_share
from amfe.model.frame import build_frame
from amfe.model.scales import bed_for, get_scale, record_seed
from run.common import parser
from run.report.continuum_ladders import bed_of

PERCENTILES = (5, 25, 50, 75, 95, 99)


def shares(bed):
    """(n,) neck share of each load-carrying particle of ``bed``."""
    f = build_frame(bed.centers, bed.radii, bed.material(), size=bed.attrs.get("size"))
    return neck_share(f.bonds.i, f.bonds.j, f.bonds.a, f.radii)


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--small", type=int, default=12, help="small beds of seed 47100")
    ap.add_argument("--plan-step", type=int, default=3, help="every k-th bed of the plan")
    args = ap.parse_args(argv)
    plan, plan_means = [], []
    for k in range(0, 185, args.plan_step):
        try:
            p = shares(bed_of(47001, k)[0])
        except AmfeError:   # a plan bed without one (recorded as such in its table)
            continue
        plan.append(p)
        plan_means.append(p.mean())
    small = [shares(bed_for(get_scale("small"), record_seed(47100, k)))
             for k in range(args.small)]
    plan_all, small_all = np.concatenate(plan), np.concatenate(small)
    print(f"plan beds: {len(plan)}, bed means {min(plan_means):.2f}-{max(plan_means):.2f}")
    print(f"  per-particle percentiles {PERCENTILES}: "
          f"{np.round(np.percentile(plan_all, PERCENTILES), 2)}")
    print(f"small beds: {len(small)}, bed means {np.round([s.mean() for s in small], 2)}")
    print(f"  per-particle percentiles {PERCENTILES}: "
          f"{np.round(np.percentile(small_all, PERCENTILES), 2)}")
    top = np.percentile(plan_all, 99)
    print(f"small beds' particles above the plan's 99th percentile ({top:.2f}): "
          f"{100 * np.mean(small_all > top):.2f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
