"""``amfe predict``'s beds that no shipped model reads as it is: any size, thickness, alloy.

A bed of a shipped size (0.6, 1.2, 3 mm), 3 layers and the paper's nu and psi
goes the shipped model's way (amfe.cli.predict_core; an E of its own scales
the moduli). Every other bed in range takes its route
(amfe.training.anypredict; docs/surrogate.md, "Any bed"): the size rule
between the shipped models for another size, the ``anybed`` network for
another thickness or nu and psi, both for both (always flagged: no held-out
beds of such a combination). Its record has the shipped records' keys, with
``route`` saying which; a bed outside every range gets a failed record whose
reason quotes its own size, layers or material (or is solved with --fallback).
"""
import math
import os
import time

from amfe.errors import AmfeError
from amfe.vocab import LABEL_NAMES as SIX

#: The anybed checkpoint in amfe/models/.
ANYBED = "anybed_small.pt"


def bed_kind(bed):
    """(size (3,) [m], Material, note or None): the box a bed is imaged in (its recorded
    size, else its spheres' box from the origin) and its material (file, else steel)."""
    import numpy as np

    from amfe.model.material import resolve_material
    from amfe.training.anypredict import CELL, LAYER
    size = bed.attrs.get("size")
    note = None
    if size is None:   # the spheres' box from the origin, to the nearest whole cell and layer
        far = np.max(np.asarray(bed.centers) + np.asarray(bed.radii)[:, None], axis=0)
        unit = np.array([CELL[0], CELL[1], LAYER])
        size = tuple(float(v) for v in np.maximum(np.round(far / unit), 1) * unit)
        note = (f"the bed file records no size: imaged on its spheres' bounding box from the "
                f"origin ({far[0] * 1e3:.4g} x {far[1] * 1e3:.4g} x {far[2] * 1e3:.4g} mm) to "
                f"the nearest whole cells and layers, {size[0] * 1e3:g} x {size[1] * 1e3:g} x "
                f"{size[2] * 1e3:g} mm")
    return tuple(float(v) for v in size), resolve_material(bed.attrs)[0], note


def needs_route(bed):
    """True when no shipped model reads ``bed`` as it is (another size, thickness, nu or psi),
    so that its route predicts it; AmfeError (quoting the bed's own values and the ranges)
    for a bed outside every range."""
    from amfe.training.anypredict import CELL, LAYER, PAPER_NU, PAPER_PSI, route_of
    from amfe.training.imagebox import cropped_box
    from amfe.training.sizerule import SIZES, check_size, size_weights
    size, material, _ = bed_kind(bed)
    check_size(size[0] * 1e3, size[1] * 1e3)      # quoting the bed's own size, not the cropped
    box = cropped_box(size, CELL)
    layers = round(size[2] / LAYER)
    lx, ly = box[0] * 1e3, box[1] * 1e3
    shipped = (layers == 3 and abs(size[2] / LAYER - 3) < 0.05
               and abs(material.nu - PAPER_NU) < 1e-9 and abs(material.psi - PAPER_PSI) < 1e-9
               and any(abs(lx - s) < 1e-6 and abs(ly - s) < 1e-6 for s in SIZES))
    if shipped:
        return False
    route_of(layers, lx, ly, material.nu, material.psi)     # refuses outside the ranges
    size_weights(lx, ly)
    return True


class Models:
    """The shipped size models, the anybed network, the networks of one thickness and the
    stack, loaded once, when first needed."""

    def __init__(self):
        self._models = None
        self.seconds = 0.0   # to load them

    def get(self):
        if self._models is None:
            t = time.perf_counter()
            from amfe.training.anypredict import load_stack_for
            from amfe.training.predict import Surrogate
            from amfe.training.shipped import SHIPPED, models_dir
            from amfe.training.sizerule import SIZES
            from amfe.training.thicknets import load_thick
            path = models_dir() / ANYBED
            if not path.is_file():
                raise AmfeError(f"the any-bed model {path} is not installed; reinstall amfe")
            anybed, thick = Surrogate.load(path), load_thick()
            self._models = {"shipped": {s: Surrogate.load(models_dir() / SHIPPED[name])
                                        for s, name in zip(SIZES, ("small", "medium", "paper"))},
                            "anybed": anybed, "thick": thick,
                            "stack": load_stack_for(anybed, thick)}
            self.seconds = time.perf_counter() - t
        return self._models


def route_record(args, models, item, times, t_start):
    """(record, rank) of a bed predicted by its route (item: (path, Bed, seconds to read))."""
    from amfe.cli.predict_common import (
        finish,
        finite_or_none,
        flag_share_note,
        given_notes,
        solve_for,
    )
    from amfe.training.anypredict import CELL, SPACING, predict_any_bed
    from amfe.training.anystack import STEEL_LAYERS
    from amfe.training.conformal import interval_block
    from amfe.training.imagebox import sampling_note
    from amfe.training.thicknets import THICK_FILES
    path, bed, t_read = item
    size, material, note = bed_kind(bed)
    got = predict_any_bed(models.get(), bed, size, material)
    mean, spread = got["mean"], got["spread"]
    bars = interval_block(mean, SIX, got["conformal"], got["box"], spread)
    reasons = ["interval"] if bars["interval_flag"] else []
    if got["route"] == "anybed x size rule":
        reasons.append("uncalibrated")
    if not all(math.isfinite(v) for v in mean):
        reasons.append("non-finite")
    times = {**times, "load_model": models.seconds, "read_bed": t_read,
             "pixelate": got["times"]["imaging"], "predict": got["times"]["predict"]}
    solver, rank = solve_for(args, bed, reasons, times)
    props = finite_or_none(dict(zip(SIX, map(float, mean))))
    notes = [n for n in (note, sampling_note(got["box"], CELL, SPACING)) if n] \
        + [f"predicted by the {got['route']} route (docs/surrogate.md, \"Any bed\")"] \
        + given_notes(args) + flag_share_note(args)
    if got["stacked"]:
        notes.append(f"anybed's stack for {got['layers']} layers"
                     + (", with the bed's 3-layer windows" if got["layers"] >= 4 else "")
                     + (", with the small model" if got["layers"] in STEEL_LAYERS else "")
                     + (f", with the {got['layers']}-layer network"
                        if got["layers"] in THICK_FILES else ""))
    out = {"bed": None if path is None else os.fspath(path), "bc": "kubc",
           "properties": props, "spread": finite_or_none(dict(zip(SIX, map(float, spread)))),
           "spread_score": None, "threshold": None,
           "intervals": bars["intervals"], "coverage": bars["coverage"],
           "interval_calibration": {**bars["calibration"], "rule": got["route"]},
           "fill": float(got["image"].mean(dtype="float64")), "fill_range": None,
           "flagged": bool(reasons), "flag_reasons": reasons, "source": "surrogate",
           "error": None, "notes": notes, "size": [float(v) for v in got["box"]],
           "model": f"route: {got['route']}", "arch": "multiscale",
           "members": int(len(models.get()["anybed"].nets)), "inputs": ["fill", "bonds"],
           "labels": "label rule 2", "route": got["route"], "layers": int(got["layers"]),
           "image_shape": list(got["image"].shape),
           "density": float(got["image"].mean(dtype="float64"))}
    if solver is not None:
        solver_props = {k: float(solver["properties"][k]) for k in solver["properties"]}
        if args.fallback and out["flagged"]:
            out.update(source="solver", properties=solver_props,
                       surrogate={"properties": props})
        if args.check:
            out["check"] = {"solver": solver_props, "relative_difference": {
                k: None if props[k] is None else (props[k] - solver_props[k])
                / abs(solver_props[k]) for k in SIX}}
        out["solver"] = solver["solver"]
    return finish(out, (path, bed), times, t_start), rank
