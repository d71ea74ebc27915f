# Probe for docs/benchmarks.md ("Free hull vertices: rtol by their share"); a research script,
# not part of amfe. Per bed with free hull vertices under KUBC: the free vertices' share of the
# Bagi strain integral (solvers/correction.py, free_strain_share) and the largest relative
# error of the nine constants against a tight reference (Cholesky, or CG + GAMG at rtol 1e-12
# beyond 20 000 particles) for CG + GAMG at several rtols, with amfe's multigrid choice and
# with unsmoothed aggregation (keys "RTOL" and "RTOL_u"). One JSON line per bed:
#   .venv/bin/python run/probes/free_hull_share.py SCALE SEED K0 K1 OUT.jsonl [RTOL ...]
#   .venv/bin/python run/probes/free_hull_share.py bed BED.h5 OUT.jsonl [RTOL ...]
import json, sys, time
import numpy as np
from amfe.dataset.record import record_seed
from amfe.io.bedfile import read_bed
from amfe.model.bed import generate_bed
from amfe.model.frame import build_frame
from amfe.model.kubc import kubc_groups
from amfe.model.options import SolveOptions
from amfe.model.scales import get_scale, sample_bed_params
from amfe.solvers.correction import free_hull_vertices, free_strain_share
from amfe.solvers.driver import homogenize_bed


def beds(argv):
    if argv[0] == "bed":
        yield argv[1], read_bed(argv[1]), argv[2], argv[3:]
        return
    scale, seed, k0, k1 = argv[0], int(argv[1]), int(argv[2]), int(argv[3])
    sc = get_scale(scale)
    for k in range(k0, k1):
        yield (f"{scale} seed {seed} #{k}", generate_bed(**sample_bed_params(sc, record_seed(seed, k))),
               argv[4], argv[5:])


def constants(res):
    return np.array(list(res["properties"].values()))


for name, bed, out, rtols in beds(sys.argv[1:]):
    rtols = [float(r) for r in rtols] or [1e-5, 1e-6, 1e-7]
    frame = build_frame(bed.centers, bed.radii, bed.material(), size=bed.attrs.get("size"))
    groups = kubc_groups(frame)
    free = free_hull_vertices(frame, groups)
    if free is None or free.size == 0:
        print(name, "no free hull vertex", flush=True)
        continue
    share = free_strain_share(frame, groups)

    def solve(**kw):
        return homogenize_bed(bed, SolveOptions(material=bed.material(), **kw)).to_dict()

    n = len(bed.centers)
    t = time.perf_counter()
    ref = solve(solver="cholesky") if n < 20000 else solve(solver="gamg", rtol=1e-12)
    row = {"bed": name, "n": n, "n_free": int(free.size), "share": share,
           "reference_seconds": time.perf_counter() - t}
    for rtol in rtols:
        for key, extra in ((f"{rtol:g}", {}), (f"{rtol:g}_u", {"pc_gamg_agg_nsmooths": "0"})):
            t = time.perf_counter()
            r = solve(solver="gamg", rtol=rtol, ksp_options=extra)
            row[key] = float(np.max(np.abs(constants(r) / constants(ref) - 1)))
            row[key + "_its"] = max(r["solver"]["iterations"])
            row[key + "_seconds"] = time.perf_counter() - t
    with open(out, "a") as f:
        f.write(json.dumps(row) + "\n")
    print(name, n, free.size, f"share {share:.2e}", " ".join(
        f"{k}: {row[k]:.1e} ({row[k + '_its']})" for r in rtols for k in (f"{r:g}", f"{r:g}_u")),
        flush=True)
