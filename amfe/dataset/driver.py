"""The MPI batch driver of ``amfe dataset``: many beds, dynamically handed out, kill-safe.

    mpirun -n N amfe dataset -o DATA.h5 --count M --seed S --scale small --ranks-per-bed k

Groups. COMM_WORLD is split into groups of k consecutive ranks
(``Split(color=rank // k)``; the last group is smaller when k does not
divide N). A group solves one bed at a time on its own communicator
(homogenize_bed is collective over it); the group's rank 0 is its leader.

Before any work. Every option is checked on every rank
(:func:`amfe.dataset.plan.check_arguments`: seed in [0, 2**64), count, ...);
world rank 0 checks the output path and takes the output's exclusive lock
``DATA.h5.lock`` (:mod:`amfe.dataset.lock`; a second run is refused, a stale
lock is reported), and only then looks at the parts and the file
(:func:`amfe.dataset.plan.prepare`). Parts that are not the record they claim
to be (another data set's, damaged) are moved to ``DATA.h5.rejected/`` and
computed again. The lock is removed at the end, also on an AmfeError.

Hand-out. No rank is a dedicated master: world rank 0 exposes two int64
counters in an MPI RMA window (``Win.Allocate``, :mod:`amfe.dataset.handout`):
the next position in the list of records still to do, and the number of
records finished in this run. A leader that needs work takes a position with an atomic
``Fetch_and_op(+1, MPI.SUM)`` under a shared passive-target lock and
broadcasts it to its group; beds of different sizes therefore balance
themselves. The to-do list (the records without a part file) is computed by
world rank 0 before anything is handed out and broadcast, so every rank
holds the same list. (With Open MPI on one node the window is shared memory
and the atomics need nothing from rank 0; with a component that needs target
progress, rank 0 enters MPI between its own beds.)

Records. Record k is a pure function of (data-set seed, k): its bed seed is
``record_seed(seed, k)``, its bed ``generate_bed(**sample_bed_params(scale,
seed_k))``; the image is ``amfe.dataset.images.pixelate`` (leader only), the labels
come from homogenize_bed on the group. Nothing depends on the rank count or on
which group takes the record, except that with k > 1 the solve's round-off
(at the solver tolerance) does.

Failures. Any exception from generation, image or solve (AmfeError, PETSc's
errors, anything derived from Exception) makes the record failed, with the
reason ("message" for AmfeError, "Type: message" otherwise); it is written like
any record and not retried. An error of the machine instead (MemoryError,
OSError, PETSc out of memory: :class:`amfe.dataset.record.MachineFault`) is
not the bed's: that record is not written, and the run stops as on a full
disk, so the same command computes it again. The ranks of a group agree on the outcome after
each phase (an allgather of the error, if any), so a failure seen by one rank
is a failure for all of them. Generation is deterministic, and homogenize_bed
raises AmfeError alike on every rank, so the group stays in step.

Kill-safety. Each leader writes its record as its own part file
(:mod:`amfe.dataset.parts`, tmp + fsync + os.replace) before it asks for more
work; a kill (any rank, any moment) loses only the beds in flight. Rerunning
the same command (after removing the stale lock the kill left) skips every
record whose part exists. A finished DATA.h5 run again with a larger count
grows: its rows are kept as they are (records 0..N-1), the parts hold
records N..M-1, and the merge copies both into the new file, which replaces
the old one only when it is whole (a kill before leaves the old file and the
parts, and the same command resumes). A part that cannot be written (a full disk) stops
the hand-out: the groups finish the beds they hold and every rank raises the
same AmfeError; the parts written are kept. When all exist, world rank 0
merges them into a temporary file, checks it, renames it onto DATA.h5 and
only then removes the parts (:func:`amfe.dataset.merge.merge_parts`).

Rebuilds. With label tables (``--from-labels``, :mod:`amfe.dataset.labels`)
the same machinery (lock, hand-out, parts, merge) makes each record by
:func:`amfe.dataset.labels.rebuild_record` on groups of one rank: the bed and
images regenerated, the bed checked against the table's digest, the labels
copied; a bed that does not regenerate stops the hand-out like a full disk.

Progress. World rank 0 shows a tqdm bar (stderr) of the records finished by
all groups, read from the window's second counter by a background thread
every half second (the window is in rank 0's memory; no MPI call), so the
bar, its rate and its ETA are the job's, not rank 0's.
"""
import os
import sys
import time
from dataclasses import dataclass, replace

from amfe.dataset.handout import FINISHED, NEXT, Progress, Window
from amfe.dataset.labels import read_tables, rebuild_record, table_options, table_params, table_run
from amfe.dataset.lock import DatasetLock, this_process
from amfe.dataset.merge import merge_parts
from amfe.dataset.parts import STATUS_OK, describe_params, run_params, write_part
from amfe.dataset.plan import (
    DatasetOptions,
    check_arguments,
    failed_share_error,
    prepare,
    rejected_lines,
)
from amfe.dataset.record import load_pixelate, make_record
from amfe.dataset.summary import final_summary
from amfe.errors import AmfeError
from amfe.io.atomic import NoSpaceError
from amfe.io.mpi import on_root
from amfe.io.paths import check_output
from amfe.model.scales import get_scale
from amfe.solvers.choice import GAMG_RTOL_AUTO, choose_solver
from amfe.solvers.ksp import DEFAULT_RTOL


def run_dataset(output, count, *, comm=None, progress=True, pixelate=None, out=None, **options):
    """Make (or finish) the data set ``output``; collective over ``comm`` (default COMM_WORLD).

    ``options``: the fields of :class:`amfe.dataset.plan.DatasetOptions` (seed,
    scale, ranks_per_bed, rtol, solver, bc, springs, max_failed_share, from_labels),
    collected into one at once. With ``from_labels`` (label tables,
    :mod:`amfe.dataset.labels`) the tables give the scale, seeds and labels:
    each record's bed and images are regenerated, the bed checked against its
    digest, and nothing is solved; ``count`` None takes every record of the
    tables; with ``solve_rest`` a larger ``count`` solves the records beyond
    the tables with their method.

    Returns, on world rank 0, a dict: complete_before (the file was already
    there), records, ok, failed, failures [(n, reason)], rejected [(k, why,
    new path)] (part files refused and recomputed), done_this_run,
    failed_this_run, seconds (wall, this run), beds_per_hour, ranks,
    solve_rank_seconds (rank-seconds inside homogenize_bed, this run),
    generate_rank_seconds, image_rank_seconds (the same for generation and
    images), busy_rank_seconds (rank-seconds from taking a record to having
    written it), work_seconds (wall time of the hand-out loop), and lines (the
    text printed); None on the other ranks. ``solver``, ``rtol``: as for
    :func:`amfe.solvers.driver.homogenize_bed` (default auto). Prints the summary
    on world rank 0 to ``out`` (default stdout). Raises AmfeError alike on every rank, before any
    work, for bad arguments, an output locked by another run
    (:mod:`amfe.dataset.lock`), a parameter mismatch with an existing file or
    parts directory, a label table that cannot be used; after the work for a
    record file that cannot be written (a full disk: the finished records are
    kept), a table record whose bed does not regenerate, a failed merge, or
    more than ``max_failed_share`` of the records failed (the file is written).
    """
    from mpi4py import MPI  # noqa: PLC0415 (heavy or optional: loaded when used)

    opts = DatasetOptions(**options)
    world = MPI.COMM_WORLD if comm is None else comm
    t_start = time.perf_counter()
    table = None
    if opts.from_labels:
        table = on_root(world, read_tables, opts.from_labels)
        count = table_run(table, count, opts.solve_rest)
        opts = table_options(table, opts)
    sc = get_scale(opts.scale)
    choose_solver({}, 2, opts.solver)  # an unknown method is refused before any work
    rtol = opts.rtol
    if rtol is None:
        rtol = DEFAULT_RTOL if opts.solver == "gamg" else GAMG_RTOL_AUTO
    check_arguments(count, opts.seed, opts.ranks_per_bed, rtol, opts.max_failed_share,
                    world.size)
    params = run_params(sc.name, opts.seed, count, rtol, opts.solver, opts.bc, opts.springs)
    if table is not None:
        params.update(table_params(table, count))
    job = _Job(world, os.fspath(output), params, sc, opts, progress, pixelate, t_start, table)
    lock = DatasetLock(job.output, world.gather(this_process(), root=0))

    def take():
        check_output(job.output)
        lock.acquire()
    on_root(world, take)
    try:
        result = _locked_run(MPI, job)
        if world.rank == 0:
            out = sys.stdout if out is None else out
            print("\n".join(result["lines"]), file=out)
            out.flush()
        if result["too_many_failed"]:
            raise AmfeError(result["too_many_failed"])
    finally:
        if world.rank == 0:
            lock.release()
    return result if world.rank == 0 else None


@dataclass(frozen=True)
class _Job:
    """One run_dataset call, as the functions below it see it."""

    world: object
    output: str
    params: dict        # run parameters (amfe.dataset.parts.run_params)
    sc: object          # the Scale
    opts: DatasetOptions
    progress: bool
    pixelate: object    # the image function, or None before _pixelate_everywhere
    t_start: float
    table: dict = None  # label tables (amfe.dataset.labels.read_tables), or None


def _locked_run(MPI, job):
    """run_dataset with the lock held: plan, work, merge; the summary dict on every rank."""
    world, output, params = job.world, job.output, job.params
    max_failed_share = job.opts.max_failed_share

    def plan_it():
        plan = prepare(output, params)
        if plan["complete"]:
            summary = final_summary(output, plan["data"], plan["attrs"], None, job.t_start,
                                    world.size)
            summary["lines"].insert(0, f"amfe dataset: {output} is already complete for these "
                                       f"parameters ({describe_params(params)}); nothing to do")
            summary.update(rejected=[], too_many_failed=failed_share_error(
                output, plan["data"], max_failed_share))
            return {"complete": True, "summary": summary}
        return plan
    plan = on_root(world, plan_it)
    if plan["complete"]:
        return plan["summary"]
    job = replace(job, pixelate=_pixelate_everywhere(MPI, world, job.pixelate))
    todo, parts = plan["todo"], plan["parts"]
    ranks_per_bed = job.opts.ranks_per_bed   # 1 for a rebuild: nothing to solve
    if world.rank == 0:
        _announce(job, plan, ranks_per_bed)
    group = world.Split(color=world.rank // ranks_per_bed, key=world.rank)
    window = Window(MPI, world)
    bar = Progress(job.progress and world.rank == 0 and len(todo) > 0, params["count"],
                   plan["n_done"], window)
    t_loop = time.perf_counter()
    try:
        stats, error = _work(job, group, window, todo, parts)
        world.Barrier()
    finally:
        bar.close()
    t_work = time.perf_counter() - t_loop
    window.free()
    group.Free()
    all_stats = world.gather(stats, root=0)
    errors = [e for e in world.allgather(error) if e]
    if errors:
        raise AmfeError(errors[0])

    def finish():
        data, attrs = merge_parts(output, parts, params,
                                  base=(output, plan["base"]) if plan["base"] else None)
        run = {k: sum(s[k] for s in all_stats)
               for k in ("done", "failed", "generate", "image", "solve", "busy")}
        run["work_seconds"] = t_work
        summary = final_summary(output, data, attrs, run, job.t_start, world.size)
        summary.update(rejected=plan["rejected"],
                       too_many_failed=failed_share_error(output, data, max_failed_share))
        return summary
    return on_root(world, finish)


def _announce(job, plan, ranks_per_bed):
    """World rank 0: the lines that say what this run does, before it does it."""
    if plan["rejected"]:
        print("\n".join(rejected_lines(plan["rejected"])), file=sys.stderr, flush=True)
    if plan["base"]:
        print(f"amfe dataset: {job.output} holds {plan['base']} records and grows to "
              f"{job.params['count']}; its records are kept, the file is replaced only when "
              f"every new one is done (they wait in {plan['parts']})", file=sys.stderr,
              flush=True)
    elif plan["grown_from"] is not None:
        print(f"amfe dataset: the run of {plan['grown_from']} records in {plan['parts']} grows "
              f"to {job.params['count']}; the records it has are kept", file=sys.stderr,
              flush=True)
    if job.progress:
        size = job.world.size
        n_groups = (size + ranks_per_bed - 1) // ranks_per_bed
        source = "" if job.table is None else (
            f" rebuilt from the labels of {', '.join(job.opts.from_labels)} (no solve)"
            if "solved_from" not in job.params else
            f": 0-{job.params['solved_from'] - 1} rebuilt from the labels of "
            f"{', '.join(job.opts.from_labels)}, the rest solved")
        print(f"amfe dataset: {job.sc.describe()}; {job.params['count']} records{source}, "
              f"{plan['n_done']} done before, {len(plan['todo'])} to do on {size} rank(s) in "
              f"{n_groups} group(s) of {ranks_per_bed}", file=sys.stderr, flush=True)


def _work(job, group, window, todo, parts):
    """The hand-out loop of one rank: (stats of its group's records, error or None).

    An error (a record that cannot be written: a full disk; a table record
    whose bed does not regenerate) stops the hand-out; the records written
    are kept.
    """
    params = job.params
    stats = {"done": 0, "failed": 0, "generate": 0.0, "image": 0.0, "solve": 0.0, "busy": 0.0}
    error = None
    while True:
        pos = window.fetch_add(NEXT) if group.rank == 0 else None
        if group.size > 1:
            pos = group.bcast(pos, root=0)
        if pos >= len(todo):
            return stats, error
        tb = time.perf_counter()
        if job.table is not None and todo[pos] < job.table["index"].shape[0]:
            rec, refused = rebuild_record(todo[pos], job.table, job.sc, group, job.pixelate)
            if refused:
                error = refused
                window.stop()
                continue
        else:
            rec = make_record(todo[pos], params["seed"], job.sc, group, pixelate=job.pixelate,
                              solve=params)
        if group.rank != 0:
            continue
        if rec.get("machine_fault"):     # not the bed's fault: unwritten, so a rerun retries it
            error = (f"record {todo[pos]} met an error of the machine, not of its bed "
                     f"({rec['machine_fault']}); it is not recorded as failed, and the records "
                     f"finished so far are kept in {parts}: fix the cause and run the same "
                     "command again")
            window.stop()
            continue
        try:
            write_part(parts, rec, params)
        except (AmfeError, OSError) as exc:   # a full disk: stop handing out, keep what is done
            error = (f"no space left on {parts}: record {todo[pos]} could not be written"
                     if isinstance(exc, NoSpaceError) else str(exc) if
                     isinstance(exc, AmfeError) else
                     f"cannot write record {todo[pos]} in {parts}: {exc.strerror or exc}")
            error += ("; the records finished so far are kept there: free some space (or fix "
                      "the directory) and run the same command again")
            window.stop()
            continue
        window.fetch_add(FINISHED)
        stats["done"] += 1
        stats["generate"] += rec["seconds"][0] * group.size
        stats["image"] += rec["seconds"][1]
        stats["solve"] += rec["seconds"][2] * group.size
        stats["busy"] += (time.perf_counter() - tb) * group.size
        stats["failed"] += rec["status"] != STATUS_OK


def _pixelate_everywhere(MPI, world, pixelate):
    """The image function on every rank, or the same AmfeError on every rank."""
    if pixelate is not None:
        return pixelate
    try:
        pixelate = load_pixelate()
    except AmfeError as exc:
        pixelate = exc
    if world.allreduce(isinstance(pixelate, AmfeError), op=MPI.LOR):
        raise AmfeError(str(pixelate) if isinstance(pixelate, AmfeError)
                        else "amfe.dataset.images.pixelate is not available on every rank")
    return pixelate

__all__ = ["run_dataset", "make_record"]
