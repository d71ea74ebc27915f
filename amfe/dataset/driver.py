"""The MPI batch driver of ``amfe dataset``: many beds, dynamically handed out, kill-safe.

    mpirun -n N amfe dataset -o DATA.h5 --count M --seed S --scale small --ranks-per-bed k

Groups. COMM_WORLD is split into groups of k consecutive ranks
(``Split(color=rank // k)``; the last group is smaller when k does not
divide N). A group solves one bed at a time on its own communicator
(homogenize_bed is collective over it); the group's rank 0 is its leader.

Hand-out. No rank is a dedicated master: world rank 0 exposes two int64
counters in an MPI RMA window (``Win.Allocate``): the next position in the
list of records still to do, and the number of records finished in this run.
A leader that needs work takes a position with an atomic
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
any record and not retried. The ranks of a group agree on the outcome after
each phase (an allgather of the error, if any), so a failure seen by one rank
is a failure for all of them. Generation is deterministic, and homogenize_bed
raises AmfeError alike on every rank, so the group stays in step.

Kill-safety. Each leader writes its record as its own part file
(:mod:`amfe.io.datasetfile`, tmp + fsync + os.replace) before it asks for more
work; a kill (any rank, any moment) loses only the beds in flight. Rerunning
the same command skips every record whose part exists. When all exist, world
rank 0 merges them into DATA.h5 (tmp + os.replace) and removes the parts.

Progress. World rank 0 shows a tqdm bar (stderr) of the records finished by
all groups, read from the window's second counter by a background thread
every half second (the window is in rank 0's memory; no MPI call), so the
bar, its rate and its ETA are the job's, not rank 0's.
"""
import json
import os
import sys
import threading
import time
import traceback

import numpy as np

from amfe.dataset.summary import final_summary
from amfe.dataset.upgrade import record_bond_image
from amfe.io.datasetfile import check_dataset, merge_parts
from amfe.io.datasetparts import (STATUS_FAILED, STATUS_OK, describe_params, done_indices,
                                  empty_record, parts_dir, read_params_json, remove_stale_tmp,
                                  run_params, write_params_json, write_part)
from amfe.model.bed import generate_bed
from amfe.errors import AmfeError
from amfe.io.mpi import on_root
from amfe.vocab import LABEL_NAMES
from amfe.model.scales import PARAM_NAMES, get_scale, param_record, record_seed, sample_bed_params
from amfe.solvers.ksp import DEFAULT_RTOL

NEXT, FINISHED = 0, 1   # the two counters of the hand-out window


def _reason(exc):
    """A failed record's reason: the AmfeError's message, else "Type: message (at file:line)"."""
    if isinstance(exc, AmfeError):
        msg = str(exc) or "AmfeError"
    else:
        msg = f"{type(exc).__name__}: {exc}"
        tb = traceback.extract_tb(exc.__traceback__)
        if tb:
            msg += f" (at {os.path.basename(tb[-1].filename)}:{tb[-1].lineno} in {tb[-1].name})"
    return msg[:1000]


def _agree(group, err):
    """The first error any rank of the group saw (None if none), the same on every rank."""
    if group.size == 1:
        return err
    for e in group.allgather(err):
        if e is not None:
            return e
    return None


def make_record(k, dataset_seed, scale, group, rtol=DEFAULT_RTOL, pixelate=None, bc="kubc"):
    """Record k (a dict, see amfe.io.datasetfile), computed collectively on ``group``.

    Every rank of ``group`` calls it with the same arguments; the record is
    complete on the group's rank 0 (the others hold no image). Never raises
    for a bad bed or a failed solve: the record says status failed and why.
    """
    from amfe.solvers.driver import homogenize_bed

    sc = get_scale(scale)
    bed_seed = record_seed(dataset_seed, k)
    rec = empty_record(k, bed_seed, sc.image_shape)
    err = None
    t0 = time.perf_counter()
    try:
        params = sample_bed_params(sc, bed_seed)
        rec["params"] = np.array([param_record(params)[n] for n in PARAM_NAMES])
        bed = generate_bed(**params)
        rec["n_particles"] = bed.n
        t1 = time.perf_counter()
        rec["seconds"][0] = t1 - t0
        if group.rank == 0:
            image = np.asarray(pixelate(bed, cell=sc.cell, layer_thickness=sc.layer_thickness,
                                        box=((0.0, 0.0, 0.0), sc.size),
                                        spacing=sc.image_spacing), np.float32)
            if image.shape != sc.image_shape:
                raise AmfeError(f"pixelate gave an image of shape {image.shape}, expected "
                                f"{sc.image_shape}")
            rec["image"] = image
            rec["bond_image"] = record_bond_image(bed, sc)
            rec["density"] = float(image.mean(dtype=np.float64))
            rec["seconds"][1] = time.perf_counter() - t1
    except Exception as exc:  # noqa: BLE001 - recorded, not fatal
        err = _reason(exc)
    err = _agree(group, err)
    if err is None:
        t2 = time.perf_counter()
        try:
            res = homogenize_bed(bed.centers, bed.radii, bed.material(), comm=group, rtol=rtol,
                                 bc=bc)
        except Exception as exc:  # noqa: BLE001
            err = _reason(exc)
        rec["seconds"][2] = time.perf_counter() - t2
        err = _agree(group, err)
    if err is not None:
        rec["status"], rec["reason"] = STATUS_FAILED, err
        return rec
    props = res["properties"]
    rec.update(status=STATUS_OK, reason="",
               labels=np.array([props[n] for n in LABEL_NAMES]),
               C=np.array(res["C"]), iterations=np.array(res["solver"]["iterations"], np.int32),
               n_removed=int(res["n_removed"]), n_bonds=int(res["n_bonds"]),
               volume=float(res["volume"]),
               solver=json.dumps(res["solver"], default=float))
    return rec


def _load_pixelate():
    try:
        from amfe.dataset.images import pixelate
    except ImportError as exc:
        raise AmfeError(f"amfe.dataset.images.pixelate is not available ({exc}); the images of a "
                        "data set need it") from None
    return pixelate


class _Window:
    """The two hand-out counters, in world rank 0's memory."""

    def __init__(self, MPI, world):
        self.MPI = MPI
        self.win = MPI.Win.Allocate(16 if world.rank == 0 else 0, 8, comm=world)
        self.local = None
        if world.rank == 0:
            self.local = np.frombuffer(self.win.tomemory(), dtype=np.int64)
            self.win.Lock(0, MPI.LOCK_EXCLUSIVE)
            self.local[:] = 0
            self.win.Unlock(0)
        world.Barrier()
        self._one = np.ones(1, np.int64)
        self._out = np.zeros(1, np.int64)

    def fetch_add(self, slot):
        MPI = self.MPI
        self.win.Lock(0, MPI.LOCK_SHARED)
        self.win.Fetch_and_op(self._one, self._out, 0, target_disp=slot, op=MPI.SUM)
        self.win.Unlock(0)
        return int(self._out[0])

    def peek_finished(self):
        """World rank 0 only: the finished counter, read from local memory (unified model)."""
        return int(self.local[FINISHED])

    def free(self):
        self.win.Free()


class _Progress:
    """tqdm bar on world rank 0, fed by a thread that reads the finished counter."""

    def __init__(self, enabled, total, initial, window):
        self.bar = None
        self.window = window
        self.initial = initial
        self._stop = threading.Event()
        self._thread = None
        if not enabled:
            return
        from tqdm import tqdm
        self.bar = tqdm(total=total, initial=initial, unit="bed", file=sys.stderr,
                        dynamic_ncols=True, mininterval=0.5, smoothing=0.05,
                        desc="amfe dataset")
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _update(self):
        n = self.initial + self.window.peek_finished()
        if n > self.bar.n:
            self.bar.update(n - self.bar.n)

    def _run(self):
        while not self._stop.wait(0.5):
            self._update()

    def close(self):
        if self.bar is None:
            return
        self._stop.set()
        self._thread.join()
        self._update()
        self.bar.close()


def _prepare(output, params):
    """World rank 0: decide what to do. Returns a plan dict; raises AmfeError."""
    output = os.fspath(output)
    parts = parts_dir(output)
    directory = os.path.dirname(os.path.abspath(output))
    if not os.path.isdir(directory):
        raise AmfeError(f"cannot write {output}: directory {directory} does not exist")
    remove_stale_tmp(directory, os.path.basename(output) + ".")
    if os.path.exists(output):
        try:
            problems, data, attrs = check_dataset(output)
        except AmfeError as exc:
            raise AmfeError(f"{output} exists and is not a data set ({exc}); remove it or "
                            "choose another -o") from None
        have = {k: attrs.get(k) for k in ("scale", "seed", "count", "rtol")}
        want = {k: params[k] for k in ("scale", "seed", "count", "rtol")}
        same = (str(have["scale"]) == want["scale"] and have["seed"] is not None
                and int(have["seed"]) == want["seed"] and have["count"] is not None
                and int(have["count"]) == want["count"] and have["rtol"] is not None
                and float(have["rtol"]) == want["rtol"])
        if not same:
            raise AmfeError(f"{output} exists and was made with other parameters "
                            f"({describe_params(attrs)}; asked: {describe_params(params)}); "
                            "remove it or choose another -o")
        if problems:
            raise AmfeError(f"{output} exists but fails its check ({'; '.join(problems)}); "
                            "remove it to make it again")
        if os.path.isdir(parts):
            import shutil
            shutil.rmtree(parts, ignore_errors=True)  # left by a kill after the merge
        return {"complete": True, "data": data, "attrs": attrs}
    os.makedirs(parts, exist_ok=True)
    old = read_params_json(parts)
    done = done_indices(parts, params["count"])
    if old is None:
        if done:
            raise AmfeError(f"{parts} holds records but no {os.path.basename(parts)}/params.json; "
                            "remove the directory to start afresh")
        write_params_json(parts, params)
    elif old != params:
        raise AmfeError(f"{parts} belongs to a run with other parameters ({describe_params(old)}; "
                        f"asked: {describe_params(params)}): rerun with those, or remove "
                        f"{parts} to start afresh")
    remove_stale_tmp(parts, "rec_")
    todo = sorted(set(range(params["count"])) - set(done))
    return {"complete": False, "todo": todo, "n_done": len(done), "parts": parts}


def run_dataset(output, count, *, seed=0, scale="small", ranks_per_bed=1, rtol=DEFAULT_RTOL,
                comm=None, progress=True, pixelate=None, out=None, bc="kubc"):
    """Make (or finish) the data set ``output``; collective over ``comm`` (default COMM_WORLD).

    Returns, on world rank 0, a dict: complete_before (the file was already
    there), records, ok, failed, failures [(n, reason)], done_this_run,
    failed_this_run, seconds (wall, this run), beds_per_hour, ranks,
    solve_rank_seconds (rank-seconds inside homogenize_bed, this run),
    generate_rank_seconds, image_rank_seconds (the same for generation and
    images), busy_rank_seconds (rank-seconds from taking a record to having
    written it), work_seconds (wall time of the hand-out loop), and lines (the
    text printed); None on the other ranks. Prints the summary on world rank 0 to
    ``out`` (default stdout). Raises AmfeError alike on every rank for bad
    arguments, a parameter mismatch with an existing file or parts directory,
    or a failed merge.
    """
    from mpi4py import MPI

    world = MPI.COMM_WORLD if comm is None else comm
    out = sys.stdout if out is None else out
    t_start = time.perf_counter()
    sc = get_scale(scale)
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
        raise AmfeError(f"--count must be a positive integer, got {count!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise AmfeError(f"--seed must be a non-negative integer, got {seed!r}")
    if not isinstance(ranks_per_bed, (int, np.integer)) or not 1 <= ranks_per_bed <= world.size:
        raise AmfeError(f"--ranks-per-bed must lie in [1, {world.size}] (the number of MPI "
                        f"ranks), got {ranks_per_bed}")
    if not 0.0 < float(rtol) < 1.0:
        raise AmfeError(f"--rtol must lie in (0, 1), got {rtol}")
    params = {**run_params(sc.name, seed, count, rtol), **({"bc": bc} if bc != "kubc" else {})}
    output = os.fspath(output)

    def prepare():
        plan = _prepare(output, params)
        if plan["complete"]:
            plan = {"complete": True, "summary": final_summary(
                output, plan["data"], plan["attrs"], None, t_start, world.size)}
        return plan
    plan = on_root(world, prepare)
    if plan["complete"]:
        if world.rank == 0:
            summary = plan["summary"]
            print(f"amfe dataset: {output} is already complete for these parameters "
                  f"({describe_params(params)}); nothing to do", file=out)
            print("\n".join(summary["lines"]), file=out)
            out.flush()
            return summary
        return None

    if pixelate is None:
        try:
            pixelate = _load_pixelate()
        except AmfeError as exc:
            pixelate = exc
        bad = world.allreduce(isinstance(pixelate, AmfeError), op=MPI.LOR)
        if bad:
            raise AmfeError(str(pixelate) if isinstance(pixelate, AmfeError)
                            else "amfe.dataset.images.pixelate is not available on every rank")

    todo = plan["todo"]
    parts = plan.get("parts", parts_dir(output))
    group = world.Split(color=world.rank // ranks_per_bed, key=world.rank)
    n_groups = (world.size + ranks_per_bed - 1) // ranks_per_bed
    window = _Window(MPI, world)
    if world.rank == 0 and progress:
        print(f"amfe dataset: {sc.describe()}; {count} records, {plan['n_done']} done before, "
              f"{len(todo)} to do on {world.size} rank(s) in {n_groups} group(s) of "
              f"{ranks_per_bed}", file=sys.stderr, flush=True)
    bar = _Progress(progress and world.rank == 0 and len(todo) > 0, count, plan["n_done"],
                    window)

    stats = {"done": 0, "failed": 0, "generate": 0.0, "image": 0.0, "solve": 0.0, "busy": 0.0,
             "reasons": []}
    t_loop = time.perf_counter()
    try:
        while True:
            pos = window.fetch_add(NEXT) if group.rank == 0 else None
            if group.size > 1:
                pos = group.bcast(pos, root=0)
            if pos >= len(todo):
                break
            k = todo[pos]
            tb = time.perf_counter()
            rec = make_record(k, seed, sc, group, rtol=rtol, pixelate=pixelate, bc=bc)
            if group.rank == 0:
                write_part(parts, rec)
                window.fetch_add(FINISHED)
                stats["done"] += 1
                stats["generate"] += rec["seconds"][0] * group.size
                stats["image"] += rec["seconds"][1]
                stats["solve"] += rec["seconds"][2] * group.size
                stats["busy"] += (time.perf_counter() - tb) * group.size
                if rec["status"] != STATUS_OK:
                    stats["failed"] += 1
                    stats["reasons"].append(rec["reason"])
        world.Barrier()
    finally:
        bar.close()
    t_work = time.perf_counter() - t_loop
    window.free()
    group.Free()
    all_stats = world.gather(stats, root=0)

    def finish():
        merge_parts(output, parts, params)
        problems, data, attrs = check_dataset(output)
        if problems:
            raise AmfeError(f"the merged file {output} fails its check: {'; '.join(problems)}")
        run = {k: sum(s[k] for s in all_stats)
               for k in ("done", "failed", "generate", "image", "solve", "busy")}
        run["work_seconds"] = t_work
        return final_summary(output, data, attrs, run, t_start, world.size)
    result = on_root(world, finish)
    if world.rank != 0:
        return None
    print("\n".join(result["lines"]), file=out)
    out.flush()
    return result


__all__ = ["run_dataset", "make_record"]
