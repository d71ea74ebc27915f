# Probe for docs/benchmarks.md ("The reaction stress to second order"); a research script, not
# part of amfe. Per bed: the largest relative error of the nine constants against Cholesky
# (or CG + GAMG at rtol 1e-12 beyond one rank / 20 000 particles), for GAMG (block path) at
# the new default rtol (with the second-order correction), the old one (1e-8, uncorrected),
# and corrected at rtol 1e-5, 1e-6 and 1e-8; with the iterations and whether amfe deems the
# bed second order (every hull vertex prescribed). One JSON line per bed. Run from the repository root:
#   .venv/bin/python run/probes/correction_rtol.py small SEED K0 K1 OUT.jsonl
#   .venv/bin/python run/probes/correction_rtol.py size LX LY LZ OUT.jsonl   (a fully scanned bed)
import json, sys, time
import numpy as np
from amfe.dataset.record import record_seed
from amfe.model.bed import generate_bed
from amfe.model.scales import get_scale, sample_bed_params
from amfe.model.frame import build_frame
from amfe.model.kubc import kubc_groups
from amfe.solvers.correction import second_order
from amfe.solvers.driver import homogenize_bed
from amfe.model.options import SolveOptions

RTOLS = [1e-5, 1e-6, 1e-8]


def beds():
    if sys.argv[1] == "small":
        seed, k0, k1 = map(int, sys.argv[2:5])
        sc = get_scale("small")
        for k in range(k0, k1):
            yield f"small seed {seed} #{k}", generate_bed(**sample_bed_params(sc, record_seed(seed, k)))
    else:
        size = [float(v) * 1e-3 for v in sys.argv[2:5]]
        yield f"size {sys.argv[2:5]}", generate_bed(size=size, seed=0)


def props(res):
    return np.array(list(res["properties"].values()))


out = sys.argv[-1]
with open(out, "a") as f:
    for name, bed in beds():
        def solve(**kw):
            return homogenize_bed(bed, SolveOptions(material=bed.material(), **kw)).to_dict()
        try:
            n = len(bed.centers)
            ref = solve(solver="cholesky") if n < 20000 else solve(solver="gamg", rtol=1e-12)
        except Exception as exc:
            print(name, "skipped:", exc, flush=True)
            continue
        row = {"bed": name, "n": n}
        frame = build_frame(*args)
        row["second_order"] = second_order(kubc_groups(frame), frame.centers)
        for rtol, corr in [(None, "yes"), (1e-8, "no")] + [(r, "yes") for r in RTOLS]:
                t = time.process_time()
                r = solve(solver="gamg", rtol=rtol, ksp_options={"amfe_correction": corr})
                key = f"{rtol or 0:g}_{corr}"
                row[key] = float(np.max(np.abs(props(r) / props(ref) - 1)))
                row[key + "_its"] = max(r["solver"]["iterations"])
                row[key + "_cpu"] = time.process_time() - t
        f.write(json.dumps(row) + "\n")
        f.flush()
        print(name, n, row["second_order"], " ".join(
            f"{k[:-4]}: {row[k]:.1e} ({row[k + '_its']})" for k in row if k.endswith(("_yes", "_no"))),
            flush=True)
