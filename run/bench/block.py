"""Six load cases in one block CG against one at a time (issue 17), in one run.

    python -m run.bench.block                          # 1.2 x 1.2 x 0.3 mm, 2 ranks
    python -m run.bench.block --size 3 3 0.3           # the paper's full bed (~4 GB/rank)
    python -m run.bench.block --scale small --repeat 3 # a data-set bed, best of 3
    python -m run.bench.block --petsc "-pc_gamg_agg_nsmooths 0" --paths block

Paths (:data:`PATHS`): block (amfe's defaults), loop (one case at a time),
uncorrected (the block path at rtol 1e-8 without the second-order stress: the
code before it) and reference (block, rtol 1e-11: each path's error is the
largest relative difference of its nine constants from this one's).
Runs each path in its own `mpirun -n RANKS` (so each has its own peak memory),
end to end: bed generation, frame, assembly, GAMG set-up, six solves,
averaging. With --repeat the later runs find memory the process already
touched (on this virtual machine that first touch costs 3-5 s/GB): the best
of several is faster than a user's single run; compare single runs. Then one more run measures, on the same bed: one MatMult with the
fine SBAIJ and AIJ matrices, one 6-column product (MAIJ, and MatMatMult with a
dense block for AIJ and SBAIJ), per path one block V-cycle on that path's GAMG
hierarchy (the block path's options differ), and a STREAM-like triad
(a = b + s c, numpy in cache-sized chunks, every rank at once). It prints
each path's lower bound for the six solves,

    bound = (V-cycles x bytes of one block V-cycle + products x bytes of one
             fine product) / triad bandwidth,

where a V-cycle reads, per level, its matrix 2 x degree times (symmetric
storage: the upper 6x6 blocks, as SBAIJ) and P twice, and every product reads
and writes a 6-column block; V-cycles = iterations + 2 and products =
iterations + 2 (PETSc's CG with an initial guess: M r0 and M b; the true
residual). Ratios of the measured solve time to the bound: before (one at a
time) and after (block). Peak memory per rank is ru_maxrss, the largest rank.
"""
import argparse
import json
import os
import resource
import shlex
import subprocess
import sys
import time

from run.common import ROOT, parser  # noqa: E402


def bed_of(args):
    from amfe.model.bed import generate_bed
    from amfe.model.scales import bed_for
    if args.scale:
        return bed_for(args.scale, args.seed)
    return generate_bed(size=tuple(v * 1e-3 for v in args.size), seed=args.seed)


PATHS = {  # name: (PETSc options, rtol (None: --rtol, else amfe's default))
    "block": ({"amfe_block": "yes"}, None),
    "loop": ({"amfe_block": "no"}, None),
    # the block path as it was before the second-order stress: rtol 1e-8, uncorrected
    "uncorrected": ({"amfe_block": "yes", "amfe_correction": "no"}, 1e-8),
    # the constants every path's error is measured against
    "reference": ({"amfe_block": "yes"}, 1e-11),
}


def worker_path(args, PETSc, comm):
    """End to end on one path; rank 0 gets the result summary."""
    from amfe.solvers.driver import homogenize_bed
    from amfe.model.options import SolveOptions
    mpi = comm.tompi4py()
    given, rtol = PATHS[args.worker]
    options = {**given, **petsc_dict(args)}
    rtol = args.rtol if rtol is None else rtol
    best = None
    for _ in range(args.repeat):
        comm.barrier()
        t0, c0 = time.perf_counter(), time.process_time()
        bed = bed_of(args)
        t_gen = time.perf_counter() - t0
        res = homogenize_bed(bed, SolveOptions(solver="gamg", rtol=rtol, ksp_options=options),
                             comm).to_dict()
        comm.barrier()
        total = time.perf_counter() - t0
        cpu = max(mpi.allgather(time.process_time() - c0))
        if best is None or total < best["total"]:
            s = res["solver"]
            best = {"total": total, "cpu": cpu, "gen": t_gen, "frame": s["frame_seconds"],
                    "assembly": s["assembly_seconds"], "setup": s["setup_seconds"],
                    "solve": s["solve_seconds"], "iterations": s["iterations"],
                    "residual": max(s["residuals"]), "particles": res["n_particles"],
                    "rtol": s["rtol"], "correction": s.get("correction"),
                    "properties": res["properties"], "C": res["C"]}
    best["peak_gb"] = max(mpi.allgather(peak_gb()))
    best["load"] = os.getloadavg()[0]
    return best


def peak_gb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # kB on Linux


def timed(comm, f, repeat=5):
    f()
    comm.barrier()
    t0 = time.perf_counter()
    for _ in range(repeat):
        f()
    comm.barrier()
    return (time.perf_counter() - t0) / repeat


def triad_bandwidth(comm, n_total=30_000_000, chunk=1 << 15):
    """Bytes/s of a = b + 3 c over all ranks at once (24 bytes an element, STREAM's count)."""
    import numpy as np
    n = n_total // comm.getSize()
    a, b, c = np.zeros(n), np.ones(n), np.ones(n)
    tmp = np.empty(chunk)

    def triad():
        for i in range(0, n, chunk):
            t = tmp[:min(chunk, n - i)]
            np.multiply(c[i:i + chunk], 3.0, out=t)
            np.add(b[i:i + chunk], t, out=a[i:i + chunk])
    return comm.getSize() * 24 * n / timed(comm, triad, 3)


def worker_measure(args, PETSc, comm):
    """Products, the triad bandwidth, and per path its hierarchy's V-cycle bytes and time."""
    import numpy as np
    from amfe.model.frame import build_frame
    from amfe.model.kubc import kubc_groups
    from amfe.solvers.assembly import local_block_rows
    from amfe.solvers.blocksolve import with_block_defaults
    from amfe.solvers.ksp import petsc_options
    from amfe.solvers.operator import ConstrainedOperator
    from amfe.solvers.partition import row_ranges
    bed = bed_of(args)
    frame = build_frame(bed.centers, bed.radii, size=bed.attrs.get("size"))
    group = kubc_groups(frame)[0]
    rank, size = comm.getRank(), comm.getSize()
    ranges = row_ranges(frame.n_particles, size)
    r0, r1 = int(ranges[rank]), int(ranges[rank + 1])
    out = {}
    for path in args.paths.split(","):
        if path == "reference":
            continue
        options = petsc_dict(args)
        if path != "loop":  # its hierarchy, but with the SBAIJ copy for the timings
            options = with_block_defaults(options)
        with petsc_options({**options, "amfe_block": "no"}):
            op = ConstrainedOperator(frame, comm, r0, r1, local_block_rows(frame, r0, r1),
                                     group, rtol=args.rtol or 1e-8)
        m = op.A.getLocalSize()[0]
        X, Y = np.random.default_rng(rank).random((m, 6)), np.empty((m, 6))
        if "t_sbaij" not in out:
            out.update(products(PETSc, comm, op, X, Y))
        out[path] = hierarchy(PETSc, comm, op, X, Y)
        op.destroy()
    out["bandwidth"] = triad_bandwidth(comm)
    out["load"] = os.getloadavg()[0]
    return out


def products(PETSc, comm, op, X, Y):
    """Seconds of one MatMult (SBAIJ, AIJ) and one 6-column product (MAIJ, MatMatMult)."""
    from amfe.solvers.maij import block_product
    S, A = op.A_op, op.A
    x, y = S.createVecs()
    out = {"t_sbaij": timed(comm, lambda: S.mult(x, y)), "t_aij": timed(comm, lambda: A.mult(x, y))}
    for name, M, backend in (("maij", A, "maij"), ("aij_dense", A, "dense"),
                             ("sbaij_dense", S, "dense")):
        try:
            prod = block_product(M, 6, backend)
            out["t_" + name] = timed(comm, lambda: prod.mult(X, Y), 3)
            prod.destroy()
        except PETSc.Error:
            out["t_" + name] = float("nan")
    info = S.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)
    out.update(sbaij_bytes=info["nz_used"] * 8 * (1 + 1 / 72),
               aij_bytes=12 * A.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"])
    return out


def hierarchy(PETSc, comm, op, X, Y, k=6):
    """A block V-cycle's and a PCApply's seconds; the bytes a V-cycle and a product must move."""
    from amfe.solvers.blockcycle import BlockVCycle
    V = BlockVCycle(op.ksp.getPC(), k)
    pc, b, x = op.ksp.getPC(), op._b[0], op._b[0].duplicate()
    out = {"t_vcycle": timed(comm, lambda: V.apply(X, Y), 3),
           "t_pcapply": timed(comm, lambda: pc.apply(b, x), 3)}
    vcycle_bytes = 0.0
    for i, lev in enumerate(V.levels):  # coarse to fine
        coarser = V.levels[i - 1].rows if i else V.coarse.b.getSize()
        vcycle_bytes += 2 * lev.degree * (sym_bytes(lev.nnz, lev.rows) + 16 * k * lev.rows)
        vcycle_bytes += 2 * (12 * lev.p_nnz + 8 * k * (lev.rows + coarser))
    fine = V.levels[-1]
    out.update(product_bytes=sym_bytes(fine.nnz, fine.rows) + 16 * k * fine.rows,
               vcycle_bytes=vcycle_bytes,
               levels=[V.coarse.b.getSize()] + [lev.rows for lev in V.levels],
               degrees=[lev.degree for lev in V.levels],
               vcycle_fine_reads=sum(2 * lev.degree * lev.nnz for lev in V.levels) / fine.nnz)
    V.destroy()
    x.destroy()
    return out


def sym_bytes(nnz, rows):
    """Bytes of a symmetric bs-6 matrix stored as its upper 6x6 blocks (values + block index)."""
    upper = (nnz + 6 * rows) / 2  # the diagonal blocks whole
    return upper * 8 + upper / 36 * 4


def petsc_dict(args):
    words = shlex.split(args.petsc)
    opts, i = {}, 0
    while i < len(words):
        key = words[i].lstrip("-")
        if i + 1 < len(words) and not words[i + 1].startswith("-"):
            opts[key], i = words[i + 1], i + 2
        else:
            opts[key], i = "", i + 1
    return opts


def run_worker(args, what):
    cmd = ["mpirun", "-n", str(args.ranks), sys.executable, "-m", "run.bench.block",
           "--worker", what, *sys.argv[1:]]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1",
               OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env)
    lines = [s for s in proc.stdout.splitlines() if s.startswith("RESULT ")]
    if proc.returncode or not lines:
        sys.exit(f"bench_block: the {what} run failed:\n{proc.stderr[-3000:]}")
    return json.loads(lines[-1][7:])


def report(args, runs):
    def say(s=""):
        print(s, flush=True)
    rel = lambda a, b: max(abs(a[k] - b[k]) / abs(b[k]) for k in b if abs(b[k]) > 1e-6)  # noqa
    say(f"# bench_block: {args.ranks} rank(s), rtol {args.rtol or 'amfe default'}, options "
        f"'{args.petsc}', bed {args.scale or args.size}, best of {args.repeat}")
    ref = runs.get("reference")
    say(f"{'path':<12} {'particles':>9} {'rtol':>6} {'gen':>6} {'frame':>6} {'asm':>6} "
        f"{'setup':>7} {'six solves':>10} {'total':>7} {'cpu':>7} {'its':>18} {'peak GB/rank':>12} "
        f"{'load':>5} {'error':>8}")
    for path in args.paths.split(","):
        r = runs[path]
        err = f"{rel(r['properties'], ref['properties']):8.1e}" if ref and path != "reference" \
            else f"{'-':>8}"
        say(f"{path:<12} {r['particles']:>9} {r['rtol']:6.0e} {r['gen']:6.2f} {r['frame']:6.2f} "
            f"{r['assembly']:6.2f} {r['setup']:7.2f} {r['solve']:10.2f} {r['total']:7.2f} "
            f"{r['cpu']:7.2f} {','.join(map(str, r['iterations'])):>18} {r['peak_gb']:12.2f} "
            f"{r['load']:5.1f} {err}")
    if ref:
        say("error: the largest relative difference of the nine constants from the reference "
            "path's (block, rtol 1e-11)")
    if "block" in runs and "uncorrected" in runs:
        b, u = runs["block"], runs["uncorrected"]
        say(f"block / uncorrected at rtol 1e-8 (the code before): end to end "
            f"{b['total'] / u['total']:.2f}, six solves {b['solve'] / u['solve']:.2f}")
    if "block" in runs and "loop" in runs:
        b, l = runs["block"], runs["loop"]
        say(f"block / one at a time: end to end {b['total'] / l['total']:.2f}, six solves "
            f"{b['solve'] / l['solve']:.2f}; constants differ by "
            f"{rel(b['properties'], l['properties']):.1e}")
    m = runs.get("measure")
    if not m:
        return
    say(f"fine SBAIJ MatMult {m['t_sbaij'] * 1e3:.1f} ms ({m['sbaij_bytes'] / 1e6:.0f} MB), AIJ "
        f"{m['t_aij'] * 1e3:.1f} ms ({m['aij_bytes'] / 1e6:.0f} MB); 6 columns: MAIJ(AIJ) "
        f"{m['t_maij'] * 1e3:.1f} ms, MatMatMult AIJ x dense {m['t_aij_dense'] * 1e3:.1f} ms, "
        f"SBAIJ x dense {m['t_sbaij_dense'] * 1e3:.1f} ms")
    bw = m["bandwidth"]
    say(f"triad bandwidth {bw / 1e9:.2f} GB/s (all ranks; load {m['load']:.1f})")
    for path in [p for p in args.paths.split(",") if p in m]:
        h, its = m[path], max(runs[path]["iterations"])
        bound = (its + 2) * (h["vcycle_bytes"] + h["product_bytes"]) / bw
        say(f"{path}: levels {h['levels']}, degrees {h['degrees']}, {h['vcycle_fine_reads']:.2f} "
            f"fine-matrix reads a V-cycle; block V-cycle (6 columns) {h['t_vcycle'] * 1e3:.1f} ms, "
            f"PCApply (1 column) {h['t_pcapply'] * 1e3:.1f} ms")
        say(f"{path}: lower bound for the six solves at {its} iterations {bound:.3f} s; "
            f"measured {runs[path]['solve']:.2f} s = {runs[path]['solve'] / bound:.1f}x the bound")


def main():
    ap = parser(__doc__)
    ap.add_argument("--size", nargs=3, type=float, default=[1.2, 1.2, 0.3], help="box [mm]")
    ap.add_argument("--scale", help="a data-set scale (small, tiny) instead of --size")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ranks", type=int, default=2)
    ap.add_argument("--rtol", type=float, default=None,
                    help="of the block and loop paths (default: amfe's)")
    ap.add_argument("--repeat", type=int, default=1, help="end-to-end runs per path (best)")
    ap.add_argument("--paths", default="block,loop,uncorrected,reference",
                    help=f"some of {', '.join(PATHS)}, comma-separated")
    ap.add_argument("--petsc", default="", help="PETSc options for every run, one string")
    ap.add_argument("--no-measure", action="store_true", help="skip products and bandwidth")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        from amfe.solvers.petsc import init_petsc
        PETSc = init_petsc()
        comm = PETSc.COMM_WORLD
        fn = worker_measure if args.worker == "measure" else worker_path
        out = fn(args, PETSc, comm)
        if comm.getRank() == 0:
            print("RESULT " + json.dumps(out), flush=True)
        return
    runs = {p: run_worker(args, p) for p in args.paths.split(",")}
    if not args.no_measure:
        runs["measure"] = run_worker(args, "measure")
    report(args, runs)


if __name__ == "__main__":
    main()
