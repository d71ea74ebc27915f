"""Measurements of the speed-against-error report (run/report/report.py); one function per section.

Every function returns plain data (dicts and lists of floats) that
run/report/report.py turns into tables, plots and report.json. Times are wall-clock
seconds on the machine the report runs on; errors are relative and
dimensionless. The beds are generated here from fixed seeds, so a rerun
measures the same beds.
"""
import math
import os
import platform
import subprocess
import sys
import time

import numpy as np

from run.common import ROOT  # noqa: E402

from amfe.vocab import CONSTANT_NAMES as CONSTANTS
LABELS = CONSTANTS[:6]
MUMPS = {"ksp_type": "preonly", "pc_type": "cholesky", "pc_factor_mat_solver_type": "mumps"}
CHOLMOD = {"ksp_type": "preonly", "pc_type": "cholesky", "pc_factor_mat_solver_type": "cholmod"}
ITERATIVE = {  # name: PETSc options over amfe's CG + GAMG default
    "CG + GAMG": {},
    # the reaction stress as it was before its second-order correction (docs/model.md, section 5)
    "CG + GAMG, uncorrected": {"amfe_correction": "no"},
    "CG + hypre BoomerAMG": {"pc_type": "hypre", "pc_hypre_type": "boomeramg"},
    "CG + Jacobi": {"pc_type": "jacobi"},
}
MPI_ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_rmaps_base_oversubscribe": "1", "OMP_NUM_THREADS": "1",
           "OPENBLAS_NUM_THREADS": "1"}


def max_rel_error(props, ref, keys=CONSTANTS):
    """max over ``keys`` of |props[k] / ref[k] - 1| (the nine constants by default)."""
    return float(max(abs(props[k] / ref[k] - 1.0) for k in keys))


def machine():
    """What the report ran on: CPU, cores, memory, library versions, date, commit."""
    from petsc4py import PETSc

    import torch
    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next(ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name"))
    except (OSError, StopIteration):
        pass
    mem = float("nan")
    try:
        with open("/proc/meminfo") as fh:
            mem = int(next(ln.split()[1] for ln in fh if ln.startswith("MemTotal"))) / 2**20
    except (OSError, StopIteration):
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, text=True,
                                capture_output=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    return {"cpu": cpu, "cores": os.cpu_count(), "memory_gib": round(mem, 1),
            "petsc": ".".join(map(str, PETSc.Sys.getVersion())), "torch": torch.__version__,
            "numpy": np.__version__, "python": platform.python_version(),
            "date": time.strftime("%Y-%m-%d %H:%M %Z"), "commit": commit}


# ------------------------------------------------------------ 1. accuracy vs cost

def pareto_bed(quick):
    """The realistic bed of section 1: a `small` data-set bed (or a smaller one for --quick)."""
    from amfe.model.bed import generate_bed
    from amfe.model.scales import bed_for, sample_bed_params
    if quick:
        p = sample_bed_params("small", 7)
        p["size"] = (0.3e-3, 0.3e-3, 0.2e-3)
        return generate_bed(**p), "a 0.3 x 0.3 x 0.2 mm bed with the scan path of `small` bed seed 7"
    return bed_for("small", 7), "`amfe pack --scale small --seed 7` (a data-set bed)"


def _solve(bed, comm, **kw):
    from amfe.solvers.driver import homogenize_bed
    from amfe.model.options import SolveOptions
    t0 = time.perf_counter()
    kw.setdefault("solver", "gamg")
    r = homogenize_bed(bed, SolveOptions(material=bed.material(), **kw), comm).to_dict()
    r["wall"] = time.perf_counter() - t0
    return r


def accuracy_vs_cost(bed, rtols, log=print, scipy_max=20_000):
    """Section 1: {reference, runs: [{method, rtol, seconds, iterations, error}], unavailable}.

    seconds = preconditioner or factor set-up + the six solves (the bonds and
    the assembly, the same for every method, are reported apart). The
    reference is CG + GAMG at rtol 1e-12; MUMPS is checked against it.
    """
    from petsc4py import PETSc

    from amfe.errors import AmfeError
    comm = PETSc.COMM_SELF
    ref = _solve(bed, comm, rtol=1e-12)
    out = {"n_particles": ref["n_particles"], "n_bonds": ref["n_bonds"],
           "reference": ref["properties"], "runs": [], "unavailable": {},
           "common_seconds": ref["solver"]["frame_seconds"] + ref["solver"]["assembly_seconds"]}
    log(f"  reference CG + GAMG rtol 1e-12: {ref['wall']:.2f} s, "
        f"{ref['n_particles']} particles, {ref['n_bonds']} bonds")
    default = _solve(bed, comm, solver="gamg")["solver"]
    out["default_rtol"] = default["rtol"]  # 1e-5 where the answer is second order, else 1e-8
    out["default_iterations"] = float(np.mean(default["iterations"]))

    def record(method, rtol, r):
        s = r["solver"]
        row = {"method": method, "rtol": rtol, "seconds": s["setup_seconds"] + s["solve_seconds"],
               "iterations": float(np.mean(s["iterations"])),
               "error": max_rel_error(r["properties"], ref["properties"])}
        out["runs"].append(row)
        log(f"  {method:<22} rtol {rtol if rtol else '-':>7}  {row['seconds']:8.3f} s  "
            f"its {row['iterations']:7.1f}  max rel err {row['error']:.2e}")

    for method, opts in ITERATIVE.items():
        for rtol in rtols:
            try:
                record(method, rtol, _solve(bed, comm, rtol=rtol, ksp_options=opts, max_it=20_000))
            except AmfeError as exc:
                out["unavailable"][method] = str(exc).splitlines()[0]
                log(f"  {method}: not available here ({out['unavailable'][method]})")
                break
    for method, opts in (("Cholesky (MUMPS)", MUMPS), ("Cholesky (CHOLMOD)", CHOLMOD)):
        try:
            record(method, None, _solve(bed, comm, ksp_options=opts))
        except AmfeError as exc:
            out["unavailable"][method] = str(exc).splitlines()[0]
            log(f"  {method}: not available here")
    if ref["n_particles"] <= scipy_max:
        record("scipy SuperLU", None, _scipy_solve(bed))
    else:
        out["unavailable"]["scipy SuperLU"] = f"skipped above {scipy_max} particles"
    return out


def direct_vs_iterative(sides, log=print):
    """Rows {side_mm, n_particles, method, seconds, error} of fully scanned 0.3 mm high beds.

    CG + GAMG at amfe's default rtol against the PETSc Cholesky factorisations
    on growing beds, one rank: how each one's set-up + solve time grows with
    the bed. Error: against the MUMPS result.
    """
    from petsc4py import PETSc

    from amfe.model.bed import generate_bed
    from amfe.errors import AmfeError
    rows = []
    for side in sides:
        bed = generate_bed(size=(side * 1e-3, side * 1e-3, 0.3e-3), seed=0)
        ref = None
        for method, opts in (("Cholesky (MUMPS)", MUMPS), ("Cholesky (CHOLMOD)", CHOLMOD),
                             ("CG + GAMG", {})):
            try:
                r = _solve(bed, PETSc.COMM_SELF, ksp_options=opts)
            except AmfeError:
                continue
            ref = ref or r
            s = r["solver"]
            rows.append({"side_mm": side, "n_particles": r["n_particles"], "method": method,
                         "seconds": s["setup_seconds"] + s["solve_seconds"],
                         "error": max_rel_error(r["properties"], ref["properties"])})
            log(f"  {side:4.2f} mm {r['n_particles']:7d} particles  {method:<20} "
                f"{rows[-1]['seconds']:8.2f} s")
    return rows


def _scipy_solve(bed):
    """scipy spsolve (SuperLU) of the same KUBC problem, in homogenize_bed's result layout."""
    from amfe.model.frame import build_frame
    from amfe.model.averages import compliance_and_constants
    from amfe.solvers.scipy_direct import kubc_stiffness_scipy
    frame = build_frame(bed.centers, bed.radii, bed.material(), size=bed.attrs.get("size"))
    C, sec = kubc_stiffness_scipy(frame, strain="bagi")
    _, props = compliance_and_constants(C * frame.stress_scale)
    return {"properties": props, "solver": {"setup_seconds": sec["factor"],
                                            "solve_seconds": sec["solve"], "iterations": [0]}}


def recommend(acc, target=1e-6):
    """The cheapest run whose constants are within ``target`` of the reference."""
    good = [r for r in acc["runs"] if r["error"] <= target]
    return min(good, key=lambda r: r["seconds"]) if good else None


def pareto_front(runs):
    """Runs not beaten by another in both time and error, sorted by time."""
    front, best = [], math.inf
    for r in sorted(runs, key=lambda r: (r["seconds"], r["error"])):
        if r["error"] < best:
            front.append(r)
            best = r["error"]
    return front


# ------------------------------------------------------------ 2./3. MPI workers

def scaling_sizes(quick, tiny=False):
    """Square bases [mm] of the fully scanned 0.3 mm high beds of section 2 (1 000 ... 295 000)."""
    if tiny:
        return [0.18, 0.3]
    return [0.18, 0.35, 0.7] if quick else [0.18, 0.35, 0.7, 1.4, 2.1, 3.0]


def _matvec_seconds(PETSc, bed, comm, repeats=20):
    """Seconds of one fine-level MatMult of the assembled AIJ stiffness (bs 6) on ``comm``."""
    from amfe.model.frame import build_frame
    from amfe.solvers.assembly import assemble_stiffness
    from amfe.solvers.partition import row_ranges
    frame = build_frame(bed.centers, bed.radii, bed.material())
    rr = row_ranges(frame.n_particles, comm.getSize())
    A = assemble_stiffness(frame, comm, int(rr[comm.getRank()]),
                           int(rr[comm.getRank() + 1]))
    x, y = A.createVecs()
    x.set(1.0)
    A.mult(x, y)
    comm.barrier()
    t0 = time.perf_counter()
    for _ in range(repeats):
        A.mult(x, y)
    comm.barrier()
    dt = (time.perf_counter() - t0) / repeats
    A.destroy()
    return dt


def worker(kind, items, path):
    """Run under mpirun: the rows of section 2 (``scaling``) or 3 (``rve``) on COMM_WORLD;
    rank 0 writes them as JSON."""
    from amfe.solvers.petsc import init_petsc
    PETSc = init_petsc([])
    from amfe.io.atomic import atomic_write
    comm = PETSc.COMM_WORLD

    def log(msg):
        if comm.getRank() == 0:
            print(msg, flush=True)
    if kind == "rve":
        from run.report import rve as report_rve
        rows = report_rve.worker(items, comm, log)
    else:
        rows = [_scaling_row(PETSc, comm, side, log) for side in items]
    if comm.getRank() == 0:
        import json
        atomic_write(path, lambda fh: fh.write(json.dumps(rows).encode()))


def _scaling_row(PETSc, comm, side, log):
    """Section 2: one fully scanned bed, base ``side`` mm, 0.3 mm high: phases and matvecs."""
    from amfe.model.bed import generate_bed
    comm.barrier()
    t0 = time.perf_counter()
    bed = generate_bed(size=(side * 1e-3, side * 1e-3, 0.3e-3), seed=0)
    t_gen = time.perf_counter() - t0
    r = _solve(bed, comm)
    s = r["solver"]
    row = {"side_mm": side, "ranks": comm.getSize(), "n_particles": r["n_particles"],
           "n_bonds": r["n_bonds"], "properties": r["properties"],
           "generate": t_gen, "bonds": s["frame_seconds"], "assemble": s["assembly_seconds"],
           "setup": s["setup_seconds"], "solves": s["solve_seconds"],
           "averages": s["average_seconds"], "total": t_gen + r["wall"],
           "iterations": float(np.mean(s["iterations"]))}
    row["matvec"] = _matvec_seconds(PETSc, bed, comm)
    row["matvecs_per_solve"] = s["solve_seconds"] / 6 / row["matvec"]
    log(f"    scaling {side:5.2f} mm, {row['ranks']} rank(s): {row['n_particles']:7d} "
        f"particles, {row['total']:7.2f} s, {row['iterations']:.1f} its")
    return row


def run_worker(kind, items, ranks, path, log=print):
    """mpirun -n RANKS python -m run.report.report --worker KIND ...; returns its rows."""
    import json
    cmd = [sys.executable, "-m", "run.report.report", "--worker", kind,
           "--items", json.dumps(items), "--worker-out", path]
    if ranks > 1 or os.environ.get("AMFE_REPORT_MPIRUN"):
        cmd = ["mpirun", "-n", str(ranks), *cmd]
    env = dict(os.environ, **MPI_ENV)
    p = subprocess.run(cmd, env=env, cwd=ROOT, text=True, stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT)
    for line in p.stdout.splitlines():
        if line.startswith("    "):
            log(line)
    if p.returncode != 0:
        raise RuntimeError(f"{kind} worker on {ranks} rank(s) failed (exit {p.returncode}):\n"
                           + p.stdout[-3000:])
    with open(path) as fh:
        return json.load(fh)


def fit_exponent(n, t):
    """Least-squares slope of log t against log n (t ~ n^p): p."""
    return float(np.polyfit(np.log(np.asarray(n, float)), np.log(np.asarray(t, float)), 1)[0])
