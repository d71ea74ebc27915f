"""Which network predicts a bed, and its members' outputs: any size, thickness and alloy.

The route (docs/surrogate.md, "Any bed"), decided by the bed's kind:

- 3 layers of the paper's nu and psi (any E): the size rule
  (amfe.training.sizerule) over the shipped 0.6, 1.2 and 3 mm models;
- other thicknesses (2-6 layers) or nu, psi (amfe.training.anybed's ranges),
  0.6 x 0.6 mm: the ``anybed`` network;
- other thicknesses or materials at another size: anybed, times the size
  rule's factor measured on the bed's 3-layer view (its lowest three layers;
  a 2-layer bed's upper layer repeated), a combination with no held-out beds
  of its own: always flagged (solve it to trust it).

E enters by scaling: every network works at 210 GPa and the moduli are
multiplied by E / 210 GPa (the Poisson ratios do not depend on E).
"""
import functools
import json
import time

import numpy as np

from amfe.dataset.bondimage import bond_image
from amfe.dataset.images import pixelate
from amfe.errors import AmfeError
from amfe.training.anybed import E_TRAINED, REFERENCE, anybed_inputs, check_bed_kind
from amfe.training.anystack import (
    STACK_FILE,
    STEEL_LAYERS,
    Reads,
    image_means,
    layer_entry,
    load_stack,
    stack,
    window_starts,
)
from amfe.training.conformal import DEFAULT_COVERAGE, DEFAULT_FLAG_HALF_WIDTH, size_key
from amfe.training.ensemble import relative_spread
from amfe.training.imagebox import HEIGHT_TOL, cropped_box, sample_spacing
from amfe.training.shipped import models_dir
from amfe.training.sizerule import inverse_size, size_weights
from amfe.training.thicknets import created_stamps, thick_members
from amfe.vocab import LABEL_NAMES

#: nu and psi this close to the paper's are the shipped models' material.
PAPER_NU, PAPER_PSI, MATERIAL_TOL = 0.28, 0.08, 1e-9
#: The route names.
ROUTES = ("size rule", "anybed", "anybed x size rule")


def route_of(layers, lx_mm, ly_mm, nu, psi):
    """The route (one of :data:`ROUTES`) of a bed; AmfeError for one outside every range."""
    check_bed_kind(layers, nu, psi)
    size_weights(lx_mm, ly_mm)        # the size range
    paper = (int(layers) == 3 and abs(nu - PAPER_NU) < MATERIAL_TOL
             and abs(psi - PAPER_PSI) < MATERIAL_TOL)
    if paper:
        return "size rule"
    small = abs(lx_mm - 0.6) < 1e-6 and abs(ly_mm - 0.6) < 1e-6
    return "anybed" if small else "anybed x size rule"


def _members(sur, x):
    """(members, n, 6) raw outputs of a Surrogate's networks on inputs x (n, c, H, W)."""
    return sur.run_members(np.ascontiguousarray(x, np.float32))


def rule_members(shipped, fill, bonds, lx_mm, ly_mm):
    """(members, n, 6): the size rule's combination of the shipped models' members.

    shipped: {size [mm]: Surrogate}; fill, bonds (n, 3, H, W): 3-layer images.
    """
    x = np.concatenate([fill, bonds], axis=1)
    return sum(w * _members(shipped[s], x) for s, w in size_weights(lx_mm, ly_mm))


def anybed_members(models, fill, bonds, nu, psi, stacked=True):
    """(members, n, 6) of the anybed network at 210 GPa: fill, bonds (n, layers, H, W), nu,
    psi (n,); with ``stacked`` and a stack for the bed's thickness in ``models["stack"]``
    (amfe.training.anystack), the stack's: a bed of 4-6 layers read with its 3-layer windows
    too, a 3-layer bed with the small model too."""
    entry = layer_entry(models.get("stack"), fill.shape[1]) if stacked else None
    if entry is None:
        return _members(models["anybed"], anybed_inputs(fill, bonds, nu, psi))
    return stack(entry["coefs"], stack_reads(models, fill, bonds, nu, psi))


def stack_reads(models, fill, bonds, nu, psi):
    """amfe.training.anystack.Reads of n beds (fill, bonds (n, layers, H, W); nu, psi (n,)):
    the network on the beds, on their 3-layer windows and, on 3-layer beds, at steel's nu
    and psi beside the small model; on beds of a thickness with a network of its own
    (amfe.training.thicknets), that network's outputs."""
    nu, psi = np.asarray(nu, np.float64), np.asarray(psi, np.float64)
    direct = _members(models["anybed"], anybed_inputs(fill, bonds, nu, psi))
    if fill.shape[1] in STEEL_LAYERS:
        extra = steel_members(models, fill, bonds)
    else:
        own = thick_members(models, fill, bonds, nu, psi)
        name = f"{fill.shape[1]}-layer network"
        extra = None if own is None else _paired(own, direct, name)[None]
    return Reads(direct, window_members(models, fill, bonds, nu, psi), nu, psi,
                 image_means(fill, bonds), extra)


def steel_members(models, fill, bonds):
    """(2, members, n, 6): the small model's members on 3-layer beds (its own kind of bed,
    learned from 40 000 steel beds) and the anybed network's on them at steel's nu and psi;
    member m of one beside member m of the other."""
    n = fill.shape[0]
    small = _members(models["shipped"][0.6], np.concatenate([fill, bonds], axis=1))
    ref = _members(models["anybed"], anybed_inputs(fill, bonds, np.full(n, REFERENCE["nu"]),
                                                   np.full(n, REFERENCE["psi"])))
    return np.stack([_paired(small, ref, "small model"), ref])


def _paired(other, anybed, name):
    """``other`` (members, n, 6), checked to have as many members as the anybed network's
    ``anybed``: the stack reads member m of each beside the other."""
    if other.shape[0] != anybed.shape[0]:
        raise AmfeError(f"the {name} has {other.shape[0]} members and the anybed network "
                        f"{anybed.shape[0]}: the stack pairs them; reinstall amfe")
    return other


def window_members(models, fill, bonds, nu, psi):
    """(members, windows, n, 6) of the anybed network on the beds' 3-layer windows, or None
    for beds of 2 or 3 layers."""
    starts = window_starts(fill.shape[1])
    if not starts:
        return None
    return np.stack([_members(models["anybed"], anybed_inputs(
        fill[:, s:s + 3], bonds[:, s:s + 3], nu, psi)) for s in starts], axis=1)


def anybed_calibration(models, layers):
    """The anybed route's interval calibration for a bed of ``layers`` layers: the stack
    file's, per thickness, else the network's own (pooled over 2-6 layers)."""
    entry = layer_entry(models.get("stack"), layers)
    if entry is not None:
        return entry["calibration"]
    return models["anybed"].ckpt["conformal"]["sizes"]["0.6x0.6"]


def load_stack_for(anybed, thick):
    """The installed stack (amfe/models/anybed_stack.json) of the Surrogate ``anybed`` and the
    networks of one thickness ``thick`` ({layers: Surrogate}, amfe.training.thicknets);
    AmfeError where it is missing (the network alone would be used silently, with the
    intervals of no thickness) or was fitted to other networks."""
    path = models_dir() / STACK_FILE
    data = load_stack(path, anybed.ckpt.get("created"))
    if data is None:
        raise AmfeError(f"the anybed stack {path} is not installed; reinstall amfe")
    if data.get("thick_networks", {}) != created_stamps(thick):
        raise AmfeError(f"{path} was fitted to the networks of one thickness of "
                        f"{data.get('thick_networks')}, not to the installed "
                        f"{created_stamps(thick)}: refit it (run/train/fit_anybed_stack.py)")
    return data


def three_layer_view(fill, bonds):
    """(fill, bonds) (n, 3, H, W): a bed's lowest three layers (a 2-layer bed's upper one
    repeated), for the size rule's factor."""
    idx = [0, 1, 2] if fill.shape[1] >= 3 else [0, 1, 1]
    return fill[:, idx], bonds[:, idx]


def any_members(models, fill, bonds, kind):
    """(members (m, n, 6) raw at the bed's E, route) of n beds of one kind.

    models: {"shipped": {size: Surrogate}, "anybed": Surrogate, "stack": the anybed stack
    or None}; fill, bonds (n, layers, H, W); kind: dict layers, lx_mm, ly_mm, nu, psi,
    E [Pa].
    """
    route = route_of(kind["layers"], kind["lx_mm"], kind["ly_mm"], kind["nu"], kind["psi"])
    n = fill.shape[0]
    if route == "size rule":
        out = rule_members(models["shipped"], fill, bonds, kind["lx_mm"], kind["ly_mm"])
    else:
        out = anybed_members(models, fill, bonds, np.full(n, kind["nu"]),
                             np.full(n, kind["psi"]))
        if route == "anybed x size rule":
            f3, b3 = three_layer_view(fill, bonds)
            at_size = rule_members(models["shipped"], f3, b3, kind["lx_mm"], kind["ly_mm"])
            at_small = _members(models["shipped"][0.6], np.concatenate([f3, b3], axis=1))
            out = out * (at_size.mean(axis=0) / at_small.mean(axis=0))[None]
    out = np.array(out, np.float64)
    out[..., :3] *= float(kind["E"]) / E_TRAINED
    return out, route


# ------------------------------------------------------------------ one bed, end to end

#: The imaging of every network here (the data sets' : docs/datasets.md, box scales).
CELL, LAYER, SPACING = (30e-6, 30e-6), 100e-6, 2.5e-6


def bed_images(bed, size):
    """(fill, bonds) (layers, H, W) float32 and the imaged box (3,) [m] of a bed of size
    ``size`` (3,) [m]: whole cells from the origin (amfe.training.imagebox), whole layers."""
    layers = int(round(float(size[2]) / LAYER))
    if layers < 1 or abs(float(size[2]) / LAYER - layers) > HEIGHT_TOL:
        raise AmfeError(f"the bed is {float(size[2]) * 1e3:g} mm high, not a whole number of "
                        f"{LAYER * 1e3:g} mm powder layers: the surrogate images whole layers "
                        "(solve it: amfe homogenize)")
    box = cropped_box((size[0], size[1], layers * LAYER), CELL)
    fill = pixelate(bed, cell=CELL, layer_thickness=LAYER, box=((0.0, 0.0, 0.0), box),
                    spacing=sample_spacing(box, CELL, SPACING))
    bonds = bond_image(bed, cell=CELL, layer_thickness=LAYER, box=((0.0, 0.0, 0.0), box))
    return np.asarray(fill, np.float32), np.asarray(bonds, np.float32), box


#: The size rule's pooled calibration, in amfe/models/ (run/train/calibrate_sizerule.py).
SIZERULE_CALIBRATION = "sizerule_calibration.json"


@functools.lru_cache(maxsize=4)
def _rule_spans(path):
    """The size rule's calibration file, read once a process (a batch reads it per bed);
    None where it is not installed."""
    try:
        with open(path) as f:
            data = json.load(f)
    except FileNotFoundError:
        return None
    if data.get("format") != "amfe.sizerule_calibration" or data.get("format_version") != 2:
        raise AmfeError(f"{path} is not a size-rule calibration of version 2")
    return data


def rule_calibration(shipped, spread, side_mm=None):
    """The size rule's conformal calibration for one bed with the ensemble spread (6,) and
    side ``side_mm`` (the L of 1/L = (1/Lx + 1/Ly)/2).

    A bed between the shipped sizes has no calibration beds of its own size: the rule's
    intervals are calibrated on beds of other sizes in the same span between shipped
    sizes (0.69-1.14 mm; 1.6 and 2.5 mm: never the test sizes), pooled per span
    (:data:`SIZERULE_CALIBRATION`; docs/surrogate.md, "Any bed"). Without that file, or
    outside its spans: per constant, the widest of the shipped models' calibrations.
    """
    data = _rule_spans(str(models_dir() / SIZERULE_CALIBRATION))
    if data is not None and side_mm is not None:
        for span in data["spans"]:
            if span["lo_mm"] <= side_mm < span["hi_mm"]:
                return span["calibration"]
    cals = [shipped[s].ckpt["conformal"]["sizes"][size_key((s * 1e-3, s * 1e-3))]
            for s in sorted(shipped)]
    q, s0 = {}, {}
    for k, name in enumerate(LABEL_NAMES):
        width = [c["quantile"][name] * (spread[k] + c["spread_scale"][name]) for c in cals]
        best = cals[int(np.argmax(width))]
        q[name], s0[name] = best["quantile"][name], best["spread_scale"][name]
    return {"n": min(int(c["n"]) for c in cals), "quantile": q, "spread_scale": s0,
            "uses_spread": True}


def predict_any_bed(models, bed, size, material):
    """A bed's prediction by its route: {mean (6,), spread (6,), conformal, route, stacked
    (read through the anybed stack), image, layers, box, times {imaging, predict} [s]}
    (mean [Pa, -] at the bed's E).

    size (3,) [m]: the bed's box (recorded, else its spheres' from the origin);
    material: its Material (E, nu, psi).
    """
    t0 = time.perf_counter()
    fill, bonds, box = bed_images(bed, size)
    t1 = time.perf_counter()
    kind = dict(layers=fill.shape[0], lx_mm=box[0] * 1e3, ly_mm=box[1] * 1e3,
                nu=float(material.nu), psi=float(material.psi), E=float(material.E))
    members, route = any_members(models, fill[None], bonds[None], kind)
    mean, spread = members.mean(axis=0)[0], relative_spread(members)[0]
    conformal = route_conformal(models, route, kind, spread, box)
    stacked = route != "size rule" and layer_entry(models.get("stack"), kind["layers"]) is not None
    return {"mean": mean, "spread": spread, "conformal": conformal, "route": route,
            "stacked": stacked,
            "image": fill, "layers": fill.shape[0], "box": box,
            "times": {"imaging": t1 - t0, "predict": time.perf_counter() - t1}}


def route_conformal(models, route, kind, spread, box):
    """The conformal block of one bed of an any-bed route (amfe.training.conformal's
    interval_block reads it): its route's calibration (the size rule's span, else anybed's
    for its thickness) at the default coverage and flag half-width. kind: as for
    :func:`any_members`; spread (6,) the bed's relative spread; box (3,) [m]."""
    if route == "size rule":
        cal = rule_calibration(models["shipped"], spread,
                               1 / inverse_size(kind["lx_mm"], kind["ly_mm"]))
    else:
        cal = anybed_calibration(models, kind["layers"])
    return {"coverage": DEFAULT_COVERAGE, "flag_half_width": DEFAULT_FLAG_HALF_WIDTH,
            "sizes": {size_key(box): cal}}
