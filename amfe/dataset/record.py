"""One data-set record: a bed regenerated from its seed, its images, and its label.

:func:`make_record` is what every group of ranks of ``amfe dataset``
(:mod:`amfe.dataset.driver`) computes for record k; the record layout is
:mod:`amfe.dataset.parts`'s.
"""
import json
import os
import time
import traceback

import numpy as np

from amfe.dataset.parts import STATUS_FAILED, STATUS_OK, empty_record
from amfe.dataset.upgrade import record_bond_image
from amfe.errors import AmfeError
from amfe.model.bed import generate_bed
from amfe.model.continuum_springs import springs_of_record
from amfe.model.options import SolveOptions
from amfe.model.scales import PARAM_NAMES, get_scale, param_record, record_seed, sample_bed_params
from amfe.solvers.driver import homogenize_bed
from amfe.solvers.ksp import DEFAULT_RTOL
from amfe.vocab import LABEL_NAMES

#: PETSc's error code for memory it could not get (PETSC_ERR_MEM).
_PETSC_ERR_MEM = 55


class MachineFault(str):
    """The reason of an error of the machine, not of the bed: memory, a file or pipe (OSError),
    PETSc's out-of-memory. A record that meets one is not written as failed (a failed record is
    kept and never retried): the run stops as on a full disk, and the same command computes the
    record again (amfe.dataset.driver)."""


def _is_machine_fault(exc):
    return isinstance(exc, (MemoryError, OSError)) or getattr(exc, "ierr", None) == _PETSC_ERR_MEM


def _reason(exc):
    """A failed record's reason: the AmfeError's message, else "Type: message (at file:line)";
    a :class:`MachineFault` for an error of the machine."""
    if isinstance(exc, AmfeError):
        msg = str(exc) or "AmfeError"
    else:
        msg = f"{type(exc).__name__}: {exc}"
        tb = traceback.extract_tb(exc.__traceback__)
        if tb:
            msg += f" (at {os.path.basename(tb[-1].filename)}:{tb[-1].lineno} in {tb[-1].name})"
    return MachineFault(msg[:1000]) if _is_machine_fault(exc) else msg[:1000]


def _agree(group, err):
    """The first error any rank of the group saw (None if none), the same on every rank."""
    if group.size == 1:
        return err
    for e in group.allgather(err):
        if e is not None:
            return e
    return None


def make_record(k, dataset_seed, scale, group, pixelate=None, solve=None):
    """Record k (a dict, see amfe.dataset.datafile), computed collectively on ``group``.

    solve: how its labels are solved, as a data set's parameters say it
    (:func:`amfe.dataset.parts.run_params`: rtol, solver, bc, springs; absent ones take
    rtol 1e-8, GAMG, KUBC and the paper's springs).

    Every rank of ``group`` calls it with the same arguments; the record is
    complete on the group's rank 0 (the others hold no image). Never raises
    for a bad bed or a failed solve: the record says status failed and why,
    and holds "machine_fault" (its reason) where the error was the machine's.
    """

    rec, bed, err = regenerate(k, dataset_seed, scale, group, pixelate)
    if err is None:
        t2 = time.perf_counter()
        try:
            res = homogenize_bed(bed, solve_options(solve or {}, bed.material()),
                                 group).to_dict()
        except Exception as exc:  # noqa: BLE001
            err = _reason(exc)
        rec["seconds"][2] = time.perf_counter() - t2
        err = _agree(group, err)
    if err is not None:
        rec["status"], rec["reason"] = STATUS_FAILED, str(err)
        if isinstance(err, MachineFault):
            rec["machine_fault"] = err
        return rec
    props = res["properties"]
    rec.update(status=STATUS_OK, reason="",
               labels=np.array([props[n] for n in LABEL_NAMES]),
               C=np.array(res["C"]), iterations=np.array(res["solver"]["iterations"], np.int32),
               n_removed=int(res["n_removed"]), n_bonds=int(res["n_bonds"]),
               volume=float(res["volume"]),
               solver=json.dumps(res["solver"], default=float))
    return rec


def solve_options(solve, material):
    """The :class:`SolveOptions` of a data set's parameters ``solve`` for a bed of ``material``."""
    return SolveOptions(material=material, rtol=solve.get("rtol", DEFAULT_RTOL),
                        solver=solve.get("solver", "gamg"), bc=solve.get("bc", "kubc"),
                        springs=springs_of_record(solve.get("springs")))


def regenerate(k, dataset_seed, scale, group, pixelate):
    """Record k before its solve: (record, bed or None, error or None), on every rank of ``group``.

    The record (status failed until labelled) holds the bed seed, the
    generation parameters, the particle count and, on the group's rank 0, the
    images and density, with their seconds; the error (the same on every rank)
    is the reason generation or imaging failed. Everything but the seconds is
    a pure function of (dataset_seed, k, scale).
    """
    sc = get_scale(scale)
    bed_seed = record_seed(dataset_seed, k)
    rec = empty_record(k, bed_seed, sc.image_shape)
    bed, err = None, None
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
                                        box=((0.0, 0.0, 0.0), sc.image_box),
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
    return rec, bed, _agree(group, err)


def load_pixelate():
    try:
        from amfe.dataset.images import pixelate  # noqa: PLC0415 (guarded: its error below)
    except ImportError as exc:
        raise AmfeError(f"amfe.dataset.images.pixelate is not available ({exc}); the images of a "
                        "data set need it") from None
    return pixelate
