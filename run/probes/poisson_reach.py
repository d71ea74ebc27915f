"""Issue 47, item 3: what Poisson ratio can the frame reach on real beds?

The affine estimate for normal and tangential springs on an isotropic packing,
nu = (k_n - k_t) / (4 k_n + k_t), is at most 1/4 (k_t -> 0); the frame gives
0.056-0.09 with the paper's springs and the continuum 0.19-0.27. On `small`
beds, the shear springs k_t (and, separately, the rotational springs kappa_n,
kappa_t) are scaled by a factor f, every other spring kept, and the bed solved
under KUBC (scipy's SuperLU, amfe.solvers.scipy_direct): the Poisson ratios and
Young's moduli as f -> 0 say how far a spring calibration can move nu.

    python -m run.probes.poisson_reach --beds 6 [--json out.json]
"""
import dataclasses

import numpy as np

from amfe.model.averages import compliance_and_constants
from amfe.model.frame import build_frame
from amfe.model.material import STEEL
from amfe.model.scales import bed_for, record_seed
from amfe.solvers.scipy_direct import kubc_stiffness_scipy
from run.common import md_table, parser, write_json

FACTORS = (1.0, 0.3, 0.1, 0.03, 0.01, 0.001)


def constants(frame):
    """The six constants [Pa, -] of a frame under KUBC (scipy)."""
    C = kubc_stiffness_scipy(frame)[0] * frame.stress_scale
    return compliance_and_constants(C)[1]


def main():
    p = parser(__doc__)
    p.add_argument("--beds", type=int, default=6)
    p.add_argument("--seed", type=int, default=47100, help="data-set seed of the `small` beds")
    p.add_argument("--json", default=None)
    args = p.parse_args()
    out = {}
    for which in ("k_t", "kappa"):
        rows = []
        for f in FACTORS:
            got = []
            for k in range(args.beds):
                bed = bed_for("small", record_seed(args.seed, k))
                frame = build_frame(bed.centers, bed.radii, STEEL, size=bed.attrs.get("size"))
                if which == "k_t":
                    frame = dataclasses.replace(frame, k_t=frame.k_t * f)
                else:
                    frame = dataclasses.replace(frame, kappa_n=frame.kappa_n * f,
                                                kappa_t=frame.kappa_t * f)
                got.append(constants(frame))
            mean = {n: float(np.mean([g[n] for g in got])) for n in got[0]}
            out.setdefault(which, {})[str(f)] = mean
            rows.append([which, f, f"{mean['Ex'] / 1e9:.1f}", f"{mean['Ez'] / 1e9:.1f}",
                         f"{mean['nu_yz']:.3f}", f"{mean['nu_xz']:.3f}", f"{mean['nu_xy']:.3f}"])
            print(rows[-1], flush=True)
    print(md_table(["scaled", "factor", "Ex (GPa)", "Ez (GPa)", "nu_yz", "nu_xz", "nu_xy"],
                   rows))
    if args.json:
        write_json(args.json, out)


if __name__ == "__main__":
    main()
