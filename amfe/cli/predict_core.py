"""The records of ``amfe predict`` and :func:`amfe.predict`: one per bed, each bed on its own.

:func:`predict_records` reads the beds, picks each one's model (the shipped one for its
size, training/shipped.py, unless a model is given), predicts each model's beds in one
batch and builds one record per bed (:func:`_one_bed`). A bed that cannot be predicted
(an unreadable file, a size no model covers, another nu or psi, an image the model
cannot read, a prediction that is not finite) gets a record of its own with source
"failed" and the reason (training/prediction.py, failed_record); with --fallback such a
bed is solved instead (source "solver"). A bed that differs from the model's material
only in E is predicted with its moduli scaled by E_bed / E_model (exact: docs/model.md).
"""
import math
import os
import time

from amfe.cli.interrupt import launcher_rank
from amfe.cli.predict_any import Models, needs_route, route_record
from amfe.cli.predict_common import (
    finish,
    finite_or_none,
    flag_share_note,
    given_notes,
    solve_bed,
    solve_for,
)
from amfe.errors import AmfeError
from amfe.io.result_meta import header
from amfe.model.material import resolve_material
from amfe.vocab import LABEL_NAMES as SIX

NINE = SIX + ("G_yz", "G_xz", "G_xy")
#: From this many beds a call loads numba's imaging kernels first (its cache, about 0.3 s)
#: where the C ones do not build (those image every bed, and need no start): a small bed
#: in 0.013 s against numpy's 0.13 s, with the same bits.
WARM_FROM = 3


def predict_records(args, items, times, t_start, cache=None):
    """(records, number of failed beds) of ``items`` (bed paths or Beds), in their order.

    args: the options of amfe predict (model, stiffness, fallback, check, threshold,
    petsc_args); times: seconds spent before (start-up) shared by every record; cache: a
    dict that keeps the loaded models between calls (a sweep's batches)."""
    from amfe.training.predict import Surrogate, check_material
    from amfe.training.prediction import scale_moduli
    from amfe.training.shipped import shipped_model_for

    if len(items) >= WARM_FROM:   # numba's imaging (no C): 0.3 s once, then 10x faster a bed
        from amfe.dataset.pixelkernel import warm
        warm()
    records, beds, chosen = [None] * len(items), [None] * len(items), [None] * len(items)
    cache = {} if cache is None else cache
    models = cache.setdefault("routes", Models())
    springs = args.springs   # None: the paper's, or the given model's own
    for k, item in enumerate(items):
        path = os.fspath(item) if isinstance(item, (str, os.PathLike)) else None
        try:
            beds[k] = _read(item, path, getattr(args, "material", None))
            if not (args.model or args.stiffness) and needs_route(beds[k][1]):
                if springs == "continuum":   # the routes' models are the paper springs'
                    raise AmfeError(_continuum_scope(beds[k][1]))
                records[k] = route_record(args, models, beds[k], times, t_start)
                continue
            chosen[k] = args.model or shipped_model_for(beds[k][1], args.stiffness,
                                                        springs or "paper")
        except AmfeError as exc:
            records[k] = _failed(args, (path, beds[k] and beds[k][1]), exc, times, t_start)
    for model in dict.fromkeys(m for m in chosen if m is not None):
        t = time.perf_counter()
        if model not in cache:
            cache[model] = Surrogate.load(model)
        sur = cache[model]
        times["load_model"] = time.perf_counter() - t
        if springs and sur.springs["name"] != springs:
            raise AmfeError(f"--model {sur.path} was trained on labels of the "
                            f"{sur.springs['name']} springs, not the {springs} springs asked for "
                            f"(--springs {springs}): give a model of {springs}-spring labels, "
                            "or leave --springs out")
        threshold = args.threshold if args.threshold is not None else sur.threshold
        if args.fallback and threshold is None and not sur.fill_range \
                and not sur.ckpt.get("conformal"):
            raise AmfeError(f"--fallback needs a flag threshold: {sur.path} is a single network "
                            "without a calibrated ensemble spread; use an ensemble (amfe train "
                            "--members 5) or give --threshold")
        factors = {}
        for k in (k for k, m in enumerate(chosen) if m == model):
            try:
                factors[k] = check_material(beds[k][1], sur.ckpt, sur.path)
            except AmfeError as exc:
                records[k] = _failed(args, beds[k][:2], exc, times, t_start)
        for k, got in zip(factors, _predict_each(sur, [beds[k][1] for k in factors])):
            path, bed, t_read = beds[k]
            try:
                if isinstance(got, AmfeError):
                    raise got
                res, image, t_pred = got
                scale_moduli(res, factors[k])
                extra = {"factor": factors[k],
                         "notes": _notes(bed, factors[k], sur) + given_notes(args)}
                records[k] = _one_bed(args, sur, threshold, (path, bed), (res, image),
                                      {**times, "read_bed": t_read, **t_pred}, t_start, extra)
            except AmfeError as exc:
                records[k] = _failed(args, (path, bed), exc, times, t_start)
    given = getattr(args, "material", None)
    for (out, _), read in zip(records, beds):
        if given and read is not None and isinstance(out.get("material"), dict):
            out["material"] = resolve_material(read[1].attrs, given, given_source=getattr(
                args, "material_source", "command line"))[1]
    return records, sum(1 for out, _ in records if out["source"] == "failed")


def _read(item, path, given=None):
    """(path, Bed, seconds to read it) of a bed path or a Bed; ``given``: material values
    (dict of E, nu, psi) that replace the bed's, so that its route, its prediction and a
    fallback solve all read them."""
    t = time.perf_counter()
    if path is not None:
        from amfe.io.bedfile import read_bed  # h5py (0.02 s): not for a Bed given as such

        bed = read_bed(item)
    else:
        bed = item
    if given:
        material = resolve_material(bed.attrs, given)[0]
        bed = type(bed)(bed.centers, bed.radii, {
            **bed.attrs, "material_E": material.E, "material_nu": material.nu,
            "material_psi": material.psi})
    return path, bed, time.perf_counter() - t


def _predict_each(sur, beds):
    """Surrogate.predict_beds of ``beds`` in one batch; if the batch fails, bed by bed, each
    one's AmfeError in its place."""
    if not beds:
        return []
    try:
        return sur.predict_beds(beds)
    except AmfeError:
        out = []
        for bed in beds:
            try:
                out.append(sur.predict_bed(bed))
            except AmfeError as exc:
                out.append(exc)
        return out


def _continuum_scope(bed):
    """Why a bed no shipped model reads as it is gets no continuum-spring prediction."""
    from amfe.cli.predict_any import bed_kind
    size, material, _ = bed_kind(bed)
    return (f"no continuum-spring surrogate for a {size[0] * 1e3:g} x {size[1] * 1e3:g} x "
            f"{size[2] * 1e3:g} mm bed of nu {material.nu:g} and psi {material.psi:g}: the "
            "continuum-spring model (--springs continuum) reads 0.6 x 0.6 x 0.3 mm beds of the "
            "paper's nu and psi (any E); solve it with amfe homogenize --springs continuum, or "
            "add --fallback")


def _notes(bed, factor, sur):
    """What the record says about how the bed was read: no recorded size, a coarser
    sampling, E scaling."""
    from amfe.training.imagebox import sampling_note
    from amfe.training.predict import _image_size
    notes = []
    size, px = _image_size(bed, sur.ckpt), sur.ckpt["pixelation"]
    if bed.attrs.get("size") is None:
        notes.append(f"the bed file records no size: imaged on its spheres' bounding box, "
                     f"{size[0] * 1e3:g} x {size[1] * 1e3:g} mm (whole cells)")
    sampling = sampling_note(size, px["image_cell"], px["image_spacing"])
    if sampling:
        notes.append(sampling)
    if factor != 1.0:
        notes.append(f"the bed's E differs from the model's material only in E: moduli scaled "
                     f"by E_bed / E_model = {factor:.6g} (exact, docs/model.md)")
    return notes


def _failed(args, item, error, times, t_start):
    """(record, rank) of a bed that cannot be predicted: solved with --fallback (when it was
    read), else source "failed" with the reason."""
    from amfe.training.prediction import failed_record
    path, bed = item
    if not (args.fallback and bed is not None):
        return failed_record(path, error, times={**times,
                                                 "total": time.perf_counter() - t_start}), \
            launcher_rank()
    from mpi4py import MPI

    from amfe.solvers.petsc import init_petsc
    init_petsc(args.petsc_args)
    t = time.perf_counter()
    solver = solve_bed(bed, args.springs or "paper")
    times = {**times, "solve": time.perf_counter() - t}
    out = {"bed": path, "bc": "kubc", "properties": {k: float(solver["properties"][k])
                                                     for k in NINE},
           "intervals": None, "coverage": None, "flagged": True, "flag_reasons": ["failed"],
           "source": "solver", "error": str(error), "size": bed.attrs.get("size"),
           "notes": [], "model": None, "springs": solver["springs"],
           "solver": solver["solver"]}
    out = {**header("predict", bed.centers, bed.radii, resolve_material(bed.attrs)[1],
                    input_path=path), **out}
    out["timings"] = {**times, "total": time.perf_counter() - t_start}
    out["seconds"] = out["timings"]["total"]
    return out, MPI.COMM_WORLD.rank


def _one_bed(args, sur, threshold, item, prediction, times, t_start, extra):
    """(result dict, rank) of one bed's prediction (and solve, with --check/--fallback).

    item: (path, Bed); prediction: (result, image) of Surrogate.predict_beds, its moduli
    already scaled by extra["factor"] (E_bed / E_model); extra["notes"]: lines for the record."""
    (path, bed), (res, image) = item, prediction
    from amfe.training.predict import _image_size, as_properties

    score = float(res["score"][0])
    reasons = flag_reasons(res, threshold, sur.n_members)
    t_flag = time.perf_counter()
    risk = (_risk(sur, bed, res, image, extra["factor"], getattr(args, "flag_share", None))
            if "non-finite" not in reasons else None)
    if risk is not None:   # the one flag (issue 46): the risk, its bin's intervals
        times["flag"] = time.perf_counter() - t_flag   # its error network reads the images
        if risk["correction"]:   # the constants the error network expects (docs/surrogate.md)
            res = {**res, "mean": res["mean"] * [risk["correction"][k] for k in SIX]}
        reasons = (["risk"] if risk["flagged"] else []) + [
            r for r in reasons if r == "non-finite" or (r == "spread" and args.threshold)]
        conformal = {"coverage": risk.pop("coverage"), "names": list(SIX),
                     "sizes": {"risk bin": risk.pop("calibration")}}
        bars = interval_of(sur, bed, res, extra["factor"], conformal,
                           [risk["interval_scale"][k] for k in SIX])
    else:
        extra = {**extra, "notes": [*extra["notes"], *flag_share_note(args)]}
        bars = interval_of(sur, bed, res, extra["factor"]) if "non-finite" not in reasons \
            else None
        if bars is not None and bars["interval_flag"]:
            reasons.append("interval")
    bad = [k for k, v in zip(SIX, res["mean"][0]) if not math.isfinite(v)]
    solver, rank = solve_for(args, bed, reasons, times, f"the model {sur.path} is damaged or "
                             f"overflows on this bed ({', '.join(bad) or 'spread'})", sur.springs)
    flagged = bool(reasons)

    surrogate_props = _properties(res)
    out = {
        "bed": None if path is None else os.fspath(path),
        "bc": "kubc",   # the labels' boundary condition (docs/model.md, section 5)
        "properties": surrogate_props,
        "spread": finite_or_none(as_properties(res["spread"][0])),
        "spread_score": score if math.isfinite(score) else None,
        "threshold": threshold,
        # Split conformal intervals at the model's nominal coverage, None where the model
        # has no calibration for the bed's size (amfe.training.conformal).
        "intervals": bars["intervals"] if bars else None,
        "coverage": bars["coverage"] if bars else None,
        "interval_calibration": bars["calibration"] if bars else None,
        "fill": float(res["fill"][0]),
        "fill_range": ([sur.fill_range["lo"], sur.fill_range["hi"]] if sur.fill_range
                       else None),
        "flagged": flagged,
        "flag_reasons": reasons,
        **({"risk": risk} if risk is not None else {}),
        "source": "surrogate", "error": None, "notes": list(extra["notes"]),
        "size": list(_image_size(bed, sur.ckpt)),   # the imaged box [m]
        "model": os.fspath(sur.path),
        "arch": sur.ckpt["arch"],
        "members": sur.n_members,
        "inputs": list(sur.inputs),
        "labels": sur.labels,            # the label rule (docs/model.md, section 5)
        "springs": sur.springs,          # the labels' bond springs (docs/model.md, s. 11)
        "image_shape": list(image.shape),
        "density": float(image.mean(dtype="float64")),
    }
    if "stiffness" in res:   # a stiffness head: C and the nine constants derived from it
        out["stiffness"] = {"C": [[float(v) for v in row] for row in res["stiffness"][0]],
                            "constants": finite_or_none(dict(zip(NINE, map(float,
                                                                            res["constants9"][0])))),
                            "voigt": "xx, yy, zz, yz, xz, xy; Pa"}
    if solver is not None:
        solver_props = {k: float(solver["properties"][k]) for k in NINE}
        if args.fallback and flagged:
            out["source"] = "solver"
            out["properties"] = solver_props
            out["surrogate"] = {"properties": surrogate_props}
        if args.check:
            out["check"] = {"solver": solver_props,
                            "relative_difference": {k: _relative(surrogate_props[k],
                                                                 solver_props[k]) for k in SIX}}
        out["solver"] = solver["solver"]
    return finish(out, (path, bed), times, t_start), rank


def interval_of(sur, bed, res, factor=1.0, conformal=None, scale=None):
    """The bed's interval block (amfe.training.conformal.interval_block) at its imaged size
    (``conformal`` with one entry, "risk bin": that calibration whatever the size);
    ``res``'s moduli scaled by ``factor`` (E_bed / E_model) are unscaled for the model's
    calibration and the intervals scaled back. scale (6,): the relative scale of the six
    constants' scores (the flag's, amfe.training.flagrisk.bed_risk) instead of the
    ensemble's spread."""
    from amfe.training.conformal import interval_block, size_key
    from amfe.training.predict import _image_size
    from amfe.training.prediction import scale_intervals
    size = _image_size(bed, sur.ckpt)
    if conformal is None:
        conformal = sur.ckpt.get("conformal")
    else:
        conformal = {**conformal, "sizes": {size_key(size): conformal["sizes"]["risk bin"]}}
    if "constants9" in res and conformal and len(conformal.get("names", ())) == 9:
        row, names, spread = res["constants9"][0].copy(), NINE, res["spread9"][0]
        row[[0, 1, 2, 6, 7, 8]] /= factor   # a stiffness head calibrated on all nine
    else:
        row, names = res["mean"][0].copy(), SIX
        spread = res["spread"][0] if scale is None else scale
        row[:3] /= factor
    return scale_intervals(interval_block(row, names, conformal, size, spread), factor)


def _risk(sur, bed, res, image, factor, share=None):
    """The bed's risk block (amfe.training.flagrisk.bed_risk, with the bin's "coverage") when
    ``sur`` is a shipped model with a flag model and the bed is of its size, else None.
    factor: E_bed / E_model; share: the calibration beds' share to flag (--flag-share; None:
    the flag file's)."""
    from amfe.training.flagrisk import bed_risk, shipped_flag
    from amfe.training.shipped import SHIPPED, models_dir
    model = shipped_flag(sur.path, models_dir(), SHIPPED)
    if model is None or tuple(image.shape[1:]) != tuple(sur.ckpt["image_shape"][1:]) \
            or image.shape[0] * 2 != sur.ckpt["image_shape"][0]:
        return None
    bonds = res["bond_image"][0] / factor   # the bed's bond image, at the model's E
    mean = res["mean"][0].copy()
    mean[:3] /= factor
    return {**bed_risk(model, image, bonds, mean, res["spread"][0], share),
            "coverage": model["coverage"]}


def flag_reasons(res, threshold, n_members):
    """Why the bed is flagged: a list of "spread", "fill", "non-finite" (empty: in distribution).

    A NaN compares false with any threshold, so a non-finite prediction is a
    reason of its own; it is never "in distribution".
    """
    reasons = []
    score = float(res["score"][0])
    if threshold is not None and n_members > 1 and score > threshold:
        reasons.append("spread")
    if bool(res["fill_out"][0]):
        reasons.append("fill")
    if bool(res["nonfinite"][0]):
        reasons.append("non-finite")
    return reasons


def _properties(res):
    """The predicted constants {name: value}: the six, and with a stiffness head the shear
    moduli too (issue 46: under properties); non-finite ones None."""
    from amfe.training.predict import as_properties
    props = as_properties(res["mean"][0])
    if "constants9" in res:
        props.update(zip(NINE[6:], map(float, res["constants9"][0, 6:])))
    return finite_or_none(props)


def _relative(value, reference):
    """(value - reference) / |reference|, None when the value is None (not finite)."""
    return None if value is None else (value - reference) / abs(reference)
