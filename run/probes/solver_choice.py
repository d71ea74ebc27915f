# Probe for docs/benchmarks.md ("The cheapest adequate solve", refit of 2026-12-02); a research
# script, not part of amfe. Per `small` bed of one data-set seed: the features --solver auto
# decides on, the CPU seconds of homogenize_bed with Cholesky and with GAMG at rtol 1e-7 (the
# block path, as amfe dataset runs it), and GAMG's largest relative error over the nine
# constants against Cholesky's. One JSON line per bed. Run from the repository root, after
# `source run/env.sh` (one BLAS thread, as amfe dataset runs), on an otherwise idle machine:
#   .venv/bin/python run/probes/solver_choice.py SEED K0 K1 OUT.jsonl
import json, sys, time
import numpy as np
from amfe.dataset.record import record_seed
from amfe.model.bed import generate_bed
from amfe.model.frame import build_frame
from amfe.model.scales import get_scale, sample_bed_params
from amfe.solvers.choice import solve_features
from amfe.solvers.driver import homogenize_bed
from amfe.model.options import SolveOptions

seed, k0, k1, out = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
sc = get_scale("small")
warm = generate_bed(**sample_bed_params(sc, record_seed(seed, k0)))
homogenize_bed(warm, SolveOptions(solver="gamg", material=warm.material()))  # imports, PETSc
with open(out, "a") as f:
    for k in range(k0, k1):
        bed = generate_bed(**sample_bed_params(sc, record_seed(seed, k)))
        try:
            feats = solve_features(build_frame(bed.centers, bed.radii, bed.material()))
        except Exception as exc:  # a bed amfe refuses: the data set records it as failed
            print(k, "skipped:", exc, flush=True)
            continue
        row = {"seed": seed, "record": k, **feats}
        props = {}
        for name, kw in (("cholesky", {"solver": "cholesky"}),
                         ("gamg", {"solver": "gamg", "rtol": 1e-7})):
            t = time.process_time()
            res = homogenize_bed(bed, SolveOptions(material=bed.material(), **kw)).to_dict()
            row[name + "_cpu"] = time.process_time() - t
            props[name] = np.array([v for v in res["properties"].values()])
            row[name + "_its"] = res["solver"]["iterations"]
        row["gamg_error"] = float(np.max(np.abs(props["gamg"] / props["cholesky"] - 1)))
        f.write(json.dumps(row) + "\n")
        f.flush()
        print(k, {key: (round(v, 3) if isinstance(v, float) else v) for key, v in row.items()
                  if key.endswith(("cpu", "error", "ratio")) or key == "n_particles"}, flush=True)
