"""Running a sweep: each bed made, solved (or predicted), and its row written on its own.

The output directory holds ``sweep.json`` (the spec, written first: a rerun with
another spec is refused), ``rows/row_<k>.json`` (one per finished bed, written
atomically: a kill loses only the beds in flight, and the same command resumes),
and the tables (:mod:`amfe.study.table`) once every row is there. One run at a
time writes a directory (its lock ``sweep.lock``, :mod:`amfe.dataset.lock`).

Under ``mpirun -n N`` the ranks form groups of ``ranks_per_bed``; the beds still to
do are cut into chunks, which the groups claim one at a time as they finish
the last (a file each in ``.claims``, created exclusively; removed at the end,
and a killed run's at the next start): a group slowed by hard beds, or rank 0
by the plot's imports, takes fewer. The chunks depend on the beds to do and the
number of groups only, and a chunk is one network pass of the surrogate: its rows
are the same on a rerun with as many ranks, and within about 1e-8 (float32 sums
batched otherwise) with other ranks or after a resume. A solve is
:func:`amfe.homogenize` on the group's communicator: the row of a bed equals
``amfe homogenize`` of that bed on as many ranks, with the same solver.
"""
import json
import logging
import os
import shutil
import sys
import time

import numpy as np

from amfe.dataset.density import solid_fraction
from amfe.dataset.lock import DatasetLock, _alive, read_lock, this_process
from amfe.errors import AmfeError
from amfe.io.atomic import write_json
from amfe.io.console import LOGGER
from amfe.model.bed import generate_bed
from amfe.model.material import STEEL, Material
from amfe.model.scanpath import ScanPath
from amfe.study.spec import SCAN, SweepSpec
from amfe.vocab import CONSTANT_NAMES

SPEC_FILE, ROWS_DIR, CLAIMS_DIR = "sweep.json", "rows", ".claims"
#: Beds a rank predicts in one network pass (--method surrogate); a kill loses at most these.
BATCH = 16


def bed_of(spec: SweepSpec, k: int):
    """Bed k of the sweep (a :class:`~amfe.model.bed.Bed`) and its point's parameters."""
    point_index, seed = spec.bed(k)
    p = {**spec.base, **spec.points[point_index]}
    scan = None
    if "track_width" in p or "hatch_spacing" in p:
        if not ("track_width" in p and "hatch_spacing" in p):
            raise AmfeError("sweep: a scan path needs both track_width and hatch_spacing "
                            "(in the grid or in the base)")
        scan = ScanPath(**{n: p[n] for n in SCAN if n in p})
    elif any(n in p for n in SCAN):
        raise AmfeError("sweep: scan parameters need track_width and hatch_spacing too")
    material = Material(**{n: p.get(n, getattr(STEEL, n)) for n in ("E", "nu", "psi")})
    kw = {n: p[n] for n in ("mean_radius", "jitter", "layer_thickness", "a_star_max") if n in p}
    if "enlargement_hi" in p:
        kw["enlargement"] = (1.05, p["enlargement_hi"])
    bed = generate_bed(tuple(spec.size), scan=scan, seed=seed, skip_seed=seed,
                       material=material, **kw)
    return bed, point_index, seed


def run_sweep(spec: SweepSpec, output, *, comm=None, progress=False, petsc_args=(),
              before=None):
    """Solve (or predict) every bed of ``spec`` not yet in ``output``; the rows, on every rank.

    before: a callable rank 0 runs once before its first bed when there are several rank
    groups (the plot's imports: the other groups take more beds meanwhile, :func:`_claimed`).

    Returns the list of row dicts of all the sweep's beds (rank 0's view; the
    same on every rank after the final broadcast).
    """
    from mpi4py import MPI

    world = comm if comm is not None else MPI.COMM_WORLD
    rows_dir = os.path.join(os.fspath(output), ROWS_DIR)
    lock, error = None, None
    ranks = world.gather(this_process(), root=0)   # every rank, named in the lock
    if world.rank == 0:
        try:
            os.makedirs(rows_dir, exist_ok=True)
            lock = DatasetLock(os.path.join(os.fspath(output), "sweep"), ranks)
            _acquire(lock)
            _check_spec(spec, output)
            _fresh_claims(output)   # a killed run's claims: its unfinished beds are to do
        except (AmfeError, OSError) as exc:
            if lock is not None:
                lock.release()
            error = str(exc)
    error = world.bcast(error, root=0)
    if error:
        raise AmfeError(error)
    try:
        done = world.bcast(_finished(rows_dir, spec.n_beds) if world.rank == 0 else None, 0)
        todo = [k for k in range(spec.n_beds) if k not in done]
        groups = max(1, world.size // spec.ranks_per_bed)
        color = min(world.rank // spec.ranks_per_bed, groups - 1)
        group = world.Split(color, world.rank)
        bar = _bar(progress and world.rank == 0, spec.n_beds, len(done))
        try:
            if before is not None and world.rank == 0 and groups > 1:
                before()   # meanwhile the other groups claim more of the beds
            worker = _Worker(spec, group, petsc_args)
            # the surrogate takes its beds in batches (one network pass each); the solver one
            # at a time
            step = BATCH if spec.method == "surrogate" else 1
            for chunk in _claimed(_chunks(todo, groups, step), output, group, groups):
                for k, row in zip(chunk, worker.rows(chunk)):
                    if group.rank == 0:
                        write_json(os.path.join(rows_dir, f"row_{k:06d}.json"), row)
                    if bar is not None:   # every group's rows so far, not rank 0's alone
                        bar.update(len(_finished(rows_dir, spec.n_beds)) - bar.n
                                   if groups > 1 else 1)
            world.Barrier()   # every group's rows are written
            if bar is not None:
                bar.update(len(_finished(rows_dir, spec.n_beds)) - bar.n)
        finally:
            if bar is not None:
                bar.close()
            group.Free()
        if world.rank == 0:
            shutil.rmtree(os.path.join(os.fspath(output), CLAIMS_DIR), ignore_errors=True)
        rows = _read_rows(rows_dir, spec.n_beds) if world.rank == 0 else None
        return world.bcast(rows, root=0)
    finally:
        if lock is not None:
            lock.release()


def _chunks(todo, groups, step):
    """``todo`` (bed indices) cut into the chunks the groups claim: guided sizes (a chunk is
    1/(2 groups) of the beds after it, so the last chunks are small and the groups end
    together), at most ``step`` beds, at least one."""
    chunks, k = [], 0
    while k < len(todo):
        n = max(1, min(step, -(-(len(todo) - k) // (2 * groups))))
        chunks.append(todo[k:k + n])
        k += n
    return chunks


def _fresh_claims(output):
    path = os.path.join(os.fspath(output), CLAIMS_DIR)
    shutil.rmtree(path, ignore_errors=True)
    os.makedirs(path)


def _claimed(chunks, output, group, groups):
    """The chunks this rank's group takes: each group's rank 0 claims the next free chunk by
    creating its file in ``output``/.claims exclusively (O_EXCL: one group wins each, on any
    file system the rows share), so a group that is slower (a harder bed, rank 0's plot)
    takes fewer, and the sweep ends when the last chunk does, not the slowest group's static
    share. One group takes them all in order, without files."""
    if groups == 1:
        yield from chunks
        return
    next_id = 0
    while True:
        if group.rank == 0:
            while next_id < len(chunks) and not _claim(output, next_id):
                next_id += 1
        next_id = group.bcast(next_id, root=0)
        if next_id >= len(chunks):
            return
        yield chunks[next_id]
        next_id += 1


def _claim(output, chunk_id):
    try:
        os.close(os.open(os.path.join(os.fspath(output), CLAIMS_DIR, f"{chunk_id:06d}"),
                         os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


def _acquire(lock):
    """Take ``lock``; a stale one, every rank of which has ended on this host (a killed sweep),
    is removed first, with a line on stderr: the rows it finished are kept."""
    try:
        lock.acquire()
    except AmfeError:
        holder = read_lock(lock.path, wait=1.0)
        ranks = (holder or {}).get("ranks") or []
        if not ranks or any(_alive(p, holder.get("boot_id")) is not False for p in ranks):
            raise
        os.remove(lock.path)
        print(f"amfe sweep: removed the lock of an earlier sweep that ended without it (pid "
              f"{holder.get('pid')}, killed?); its finished rows are kept", file=sys.stderr)
        lock.acquire()


def _check_spec(spec, output):
    path = os.path.join(os.fspath(output), SPEC_FILE)
    if os.path.exists(path):
        with open(path) as f:
            old = json.load(f)
        if json.dumps(old, sort_keys=True) != spec.fingerprint():
            raise AmfeError(f"{os.fspath(output)} holds another sweep (its {SPEC_FILE} differs "
                            "from this one's); give another output directory, or the same "
                            "grid, seeds, size and method to resume it")
    else:
        write_json(path, spec.to_dict())


def _finished(rows_dir, n):
    return {int(name[4:10]) for name in os.listdir(rows_dir)
            if name.startswith("row_") and name.endswith(".json") and int(name[4:10]) < n}


def _read_rows(rows_dir, n):
    rows = []
    for k in range(n):
        with open(os.path.join(rows_dir, f"row_{k:06d}.json")) as f:
            rows.append(json.load(f))
    return rows


def _bar(enabled, total, initial):
    if not enabled:
        return None
    from tqdm import tqdm  # noqa: PLC0415 (loaded when used: a bar is asked for)

    return tqdm(total=total, initial=initial, unit="bed", file=sys.stderr, desc="amfe sweep",
                dynamic_ncols=True, mininterval=0.5)


class _Worker:
    """Makes and solves (or predicts) beds on one rank group."""

    def __init__(self, spec, group, petsc_args):
        self.spec, self.group, self.petsc_args = spec, group, tuple(petsc_args)
        self.surrogates = {}

    def rows(self, ks):
        """The rows of beds ``ks``; a bed that cannot be made or solved is a row with its error
        (no constants), not the end of the sweep. seconds: the bed's share of the batch."""
        t0 = time.perf_counter()
        rows, beds = [], []
        for k in ks:
            point, seed = self.spec.bed(k)
            row = {"index": k, "point": point, "seed": seed, **self.spec.points[point]}
            try:
                bed = bed_of(self.spec, k)[0]
                row["n_particles"] = int(bed.n)
                if self.spec.method != "surrogate":   # the surrogate's: its image's mean
                    lo, hi = np.zeros(3), np.asarray(bed.attrs["size"], dtype=float)
                    row["solid_fraction"] = solid_fraction(bed.centers, bed.radii, lo, hi)[0]
                beds.append(bed)
            except AmfeError as exc:
                row.update(source="failed", error=str(exc))
                beds.append(None)
            rows.append(row)
        ok = [i for i, b in enumerate(beds) if b is not None]
        if self.spec.method == "surrogate" and ok:
            # torch and the model only for a surrogate sweep, not on a solver one's start-up
            from amfe.study.surrogate import predict_rows
            for i, part in zip(ok, predict_rows(self.surrogates, [beds[i] for i in ok],
                                                self.spec.springs, self.spec.flag_share)):
                rows[i].update(part)
        for i in ok:
            if self.spec.method == "surrogate" and not (rows[i]["flagged"]
                                                         and self.spec.fallback):
                continue
            try:
                if "solid_fraction" not in rows[i]:   # a surrogate row solved after all
                    lo, hi = np.zeros(3), np.asarray(beds[i].attrs["size"], dtype=float)
                    rows[i]["solid_fraction"] = solid_fraction(beds[i].centers, beds[i].radii,
                                                               lo, hi)[0]
                rows[i].update(self._solve(beds[i]), source="solver")
            except AmfeError as exc:
                rows[i].update(source="failed", error=str(exc))
        for row in rows:
            row["seconds"] = (time.perf_counter() - t0) / len(rows)
        return rows

    def _solve(self, bed):
        # the solver's modules only for a bed that is solved: a surrogate sweep's ranks start
        # without them
        from amfe.api import homogenize  # noqa: PLC0415

        options = {} if not self.petsc_args else {"petsc_options": _as_dict(self.petsc_args)}
        logger = logging.getLogger(LOGGER)
        level = logger.level
        logger.setLevel(logging.ERROR)   # a bed's warnings go to its row, not the terminal
        try:
            result = homogenize(bed, comm=self.group, solver=self.spec.solver,
                                rtol=self.spec.rtol, springs=self.spec.springs, **options)
        finally:
            logger.setLevel(level)
        return {**{name: float(result.properties[name]) for name in CONSTANT_NAMES},
                "n_removed": int(result.n_removed),
                "warnings": " | ".join(result.extra.get("warnings", []))}


def _as_dict(args):
    """PETSc command-line options ["-ksp_monitor", "-pc_type", "gamg"] as {name: value}."""
    out, k = {}, 0
    while k < len(args):
        name = args[k].lstrip("-")
        value = None
        if k + 1 < len(args) and not args[k + 1].startswith("-"):
            value, k = args[k + 1], k + 1
        out[name] = value
        k += 1
    return out
