"""What a loaded checkpoint's fields must hold, checked before anything is built from them.

A checkpoint is read with a weights-only load (:mod:`amfe.training.checkpoint`),
which refuses code but accepts any plain data: strings where tensors belong,
weights of the wrong shape, a NaN threshold. :func:`check_fields` refuses
such junk with one :class:`amfe.errors.AmfeError` line naming the field, and
:func:`check_members` compares every member's weights with the network the
checkpoint describes (the multi-scale network's shapes from amfe.training.npnet,
any other built on torch's "meta" device: shapes only, no memory, so a junk
image shape or width cannot make it allocate).

Non-finite *weights* are not refused here: the prediction they give is
flagged as non-finite (:mod:`amfe.training.predict`), so ``amfe predict
--fallback`` can still solve the bed instead.
"""
import math
import sys
from collections.abc import Mapping

import numpy as np

from amfe.errors import AmfeError

MAX_SAMPLES_PER_CELL_SIDE = 64   # pixelation sample lines per cell side (data sets use 12)


def _finite_numbers(value, n, what, path, positive=False, nonnegative=False):
    """``value`` as a list of n (None: 2 or more) finite floats (> 0 with ``positive``, >= 0
    with ``nonnegative``); a bare number counts as a list of one. AmfeError otherwise."""
    if isinstance(value, (int, float)) and not isinstance(value, bool) and n == 1:
        value = [value]
    ok = isinstance(value, (list, tuple)) and (len(value) == n if n else len(value) >= 2)
    ok = ok and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                    and math.isfinite(v) for v in value)
    ok = ok and not (positive and any(v <= 0 for v in value))
    ok = ok and not (nonnegative and any(v < 0 for v in value))
    if not ok:
        need = ("positive " if positive else "non-negative " if nonnegative else "") + "finite"
        count = {None: f"2 or more {need} numbers", 1: f"a {need} number"}.get(n, f"{n} {need} "
                                                                            "numbers")
        raise AmfeError(f"{path}: {what} must be {count}, got {value!r}; not a valid amfe "
                        "checkpoint")
    return [float(v) for v in value]


def _mapping(ckpt, key, path, optional=False):
    value = ckpt.get(key)
    if value is None and optional:
        return None
    if not isinstance(value, Mapping):
        raise AmfeError(f"{path}: {key} must be a dict, got {type(value).__name__}; not a valid "
                        "amfe checkpoint")
    return value


def check_fields(ckpt, path):
    """AmfeError unless the checkpoint's non-weight fields are well formed (see the module doc)."""
    if not isinstance(ckpt.get("arch"), str):
        raise AmfeError(f"{path}: arch must be a network name, got {ckpt.get('arch')!r}")
    _mapping(ckpt, "arch_args", path)
    shape = ckpt.get("image_shape")
    if not (isinstance(shape, (list, tuple)) and len(shape) == 3
            and all(type(s) is int and s >= 1 for s in shape)):
        raise AmfeError(f"{path}: image_shape must be three positive integers (layers, H, W), "
                        f"got {shape!r}; not a valid amfe checkpoint")
    norm = _mapping(ckpt, "normalizer", path)
    _finite_numbers(norm.get("mean"), 6, "normalizer mean", path)
    _finite_numbers(norm.get("std"), 6, "normalizer std", path, positive=True)
    log = norm.get("log")
    if not (isinstance(log, (list, tuple)) and len(log) == 6 and all(type(v) is bool for v in log)):
        raise AmfeError(f"{path}: normalizer log must be 6 booleans, got {log!r}")
    px = _mapping(ckpt, "pixelation", path)
    _finite_numbers(px.get("bed_size"), 3, "pixelation bed_size", path, positive=True)
    cell = _finite_numbers(px.get("image_cell"), None, "pixelation image_cell", path, positive=True)
    _finite_numbers(px.get("layer_thickness"), 1, "pixelation layer_thickness", path,
                    positive=True)
    spacing = _finite_numbers(px.get("image_spacing"), 1, "pixelation image_spacing", path,
                              positive=True)[0]
    if max(cell[:2]) / spacing > MAX_SAMPLES_PER_CELL_SIDE:
        raise AmfeError(f"{path}: pixelation image_spacing {spacing:g} m gives more than "
                        f"{MAX_SAMPLES_PER_CELL_SIDE} samples per side of a {max(cell[:2]):g} m "
                        "cell; not a valid amfe checkpoint")
    spread = _mapping(ckpt, "spread", path, optional=True)
    if spread is not None:
        _finite_numbers(spread.get("scale"), 6, "spread scale", path, positive=True)
        _finite_numbers(spread.get("threshold"), 1, "spread threshold", path, nonnegative=True)
    fill = _mapping(ckpt, "fill_range", path, optional=True)
    if fill is not None:
        lo, hi = _finite_numbers([fill.get("lo"), fill.get("hi")], 2, "fill_range lo, hi", path)
        if lo > hi:
            raise AmfeError(f"{path}: fill_range has lo {lo} > hi {hi}")
    material = _mapping(ckpt, "material", path, optional=True)
    if material:
        _finite_numbers([material.get(k) for k in ("E", "nu", "psi")], 3, "material E, nu, psi",
                        path)
    inputs = ckpt.get("inputs", ["fill"])
    if not (isinstance(inputs, (list, tuple)) and all(isinstance(k, str) for k in inputs)):
        raise AmfeError(f"{path}: inputs must be a list of image kinds, got {inputs!r}")


def check_members(ckpt, path):
    """AmfeError unless every member holds exactly the weights of the network ``ckpt`` describes.

    The weights' shapes come from amfe.training.npnet for the multi-scale network (no
    torch), else from the network built on torch's meta device (no memory); each member
    must be a dict with its parameter names, floating-point tensors (or the numpy
    arrays of amfe.training.torchfile) of its shapes.
    """
    want = _template_shapes(ckpt, path)
    where = f"for images {tuple(ckpt['image_shape'])}"
    for k, state in enumerate(ckpt["members"]):
        if not isinstance(state, Mapping):
            raise AmfeError(f"{path}: member {k} is a {type(state).__name__}, not a dict of "
                            "weight tensors; not a valid amfe checkpoint")
        missing = [n for n in want if n not in state]
        extra = [n for n in state if n not in want]
        if missing or extra:
            raise AmfeError(f"{path}: the weights of member {k} do not fit a {ckpt['arch']} net "
                            f"{where}: missing {_few(missing)}, unexpected {_few(extra)}")
        for name, shape in want.items():
            value = state[name]
            floating, kind = _weight_kind(value)
            if not floating:
                raise AmfeError(f"{path}: weight {name!r} of member {k} is a {kind}, not a "
                                "floating-point tensor; not a valid amfe checkpoint")
            if tuple(value.shape) != shape:
                raise AmfeError(f"{path}: weight {name!r} of member {k} has shape "
                                f"{tuple(value.shape)}, a {ckpt['arch']} net {where} needs "
                                f"{shape}")


def _template_shapes(ckpt, path):
    """{name: shape} of the weights of the network ``ckpt`` describes (AmfeError for junk)."""
    arch, args = ckpt["arch"], ckpt["arch_args"]
    try:
        if arch == "multiscale":
            from amfe.training import check_arch_args
            from amfe.training.npnet import multiscale_shapes
            return multiscale_shapes(ckpt["image_shape"], **check_arch_args(arch, args))
        import torch

        from amfe.training.nets import build_net
        with torch.device("meta"):
            template = build_net(arch, ckpt["image_shape"], args)
        return {k: tuple(v.shape) for k, v in template.state_dict().items()}
    except AmfeError as exc:
        raise AmfeError(f"{path}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - junk arch_args (a string width, negative sizes)
        raise AmfeError(f"{path}: cannot build a {arch} net from arch_args {args!r} "
                        f"({type(exc).__name__}: {exc}); not a valid amfe checkpoint") from None


def _weight_kind(value):
    """(is floating point, what it is) of a weight: a torch tensor or a numpy array."""
    if isinstance(value, np.ndarray):
        return value.dtype.kind == "f", f"array of {value.dtype}"
    torch = sys.modules.get("torch")   # a tensor exists only once torch is imported
    if torch is not None and isinstance(value, torch.Tensor):
        return value.is_floating_point(), f"tensor of {value.dtype}"
    return False, type(value).__name__


def _few(names, limit=3):
    names = list(names)
    if not names:
        return "none"
    return ", ".join(names[:limit]) + (f" (+{len(names) - limit} more)" if len(names) > limit
                                       else "")
