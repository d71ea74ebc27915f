"""Surrogate checkpoints: plain data only, loaded with ``torch.load(weights_only=True)``.

A checkpoint is ``torch.save`` of one dict that holds nothing but tensors,
ints, floats, bools, strings, None, lists and dicts:

    format "amfe.surrogate", format_version 1
    arch, arch_args          network name and the keyword arguments that rebuild it
    members                  list of state dicts (one per ensemble member; 1 for a single net)
    member_seeds             their training seeds
    normalizer               {mean, std, log, labels} (amfe.training.data.Normalizer)
    image_shape              [layers, H, W]
    pixelation               {scale, bed_size, image_cell, layer_thickness, image_spacing}:
                             how amfe predict pixelates a bed exactly as the training data
    material                 {E, nu, psi, density} of the training beds' particles
    dataset                  {path, sha256, rows, seed, scale}
    training                 {epochs, batch_size, lr, ...} and per-member history
    tta                      average over the four mirror images at inference
    spread                   {scale [6], threshold, definition} of the ensemble flag, or None
    metrics                  validation metrics (and held-out ones if evaluated)
    amfe_version, torch_version, created

Loading never unpickles code: a file that holds any other object is refused
with :class:`amfe.errors.AmfeError` ("... not a plain amfe checkpoint"), as
is one whose image shape does not match the images it is asked to predict
(:func:`check_image_shape`).
"""
import datetime
import json
import os
import pickle
from collections import OrderedDict

import numpy as np

from amfe.errors import AmfeError
from amfe.io.atomic import atomic_write
from amfe.training import ARCH_NAMES, STIFFNESS_HEAD
from amfe.training.torchfile import TensorArray, read_pickle, read_torch_file
from amfe.training.validate import check_fields, check_members
from amfe.version import __version__

FORMAT = "amfe.surrogate"
FORMAT_VERSION = 1
REQUIRED = ("format", "format_version", "arch", "arch_args", "members", "normalizer",
            "image_shape", "pixelation")


def save_checkpoint(path, ckpt):
    """Write ``ckpt`` (a dict of plain data, see the module docstring) atomically to ``path``."""
    import torch
    ckpt = dict(ckpt)
    ckpt.setdefault("format", FORMAT)
    ckpt.setdefault("format_version", FORMAT_VERSION)
    ckpt.setdefault("amfe_version", __version__)
    ckpt.setdefault("torch_version", str(torch.__version__))
    ckpt.setdefault("created", datetime.datetime.now(datetime.timezone.utc).isoformat(
        timespec="seconds"))
    ckpt = _plain(ckpt, "checkpoint")
    directory = os.path.dirname(os.path.abspath(os.fspath(path)))
    os.makedirs(directory, exist_ok=True)
    atomic_write(path, lambda fh: torch.save(ckpt, fh))
    return path


def _plain(obj, where):
    """``obj`` as builtin plain data (numpy scalars and str subclasses converted); else AmfeError.

    A weights-only load reads back nothing else: a str subclass such as
    torch.__version__ or a numpy float would be a pickled class. A TensorArray (a tensor
    read without torch, :func:`load_checkpoint` with ``arrays``) is written as a tensor.
    """
    import torch
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu()
    if isinstance(obj, TensorArray):
        return torch.from_numpy(np.array(obj))
    if obj is None or type(obj) in (bool, int, float, str):
        return obj
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj)
    if isinstance(obj, str):
        return str(obj)
    if isinstance(obj, dict):
        out = type(obj)() if isinstance(obj, OrderedDict) else {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise AmfeError(f"{where}: key {k!r} is not a string")
            out[str(k)] = _plain(v, f"{where}.{k}")
        return out
    if isinstance(obj, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, np.ndarray) and obj.dtype.kind in "biuf":
        return obj.tolist()
    raise AmfeError(f"{where}: {type(obj).__name__} is not plain data (tensors, numbers, "
                    "strings, lists, dicts); a checkpoint holds nothing else")


def _check_signature(path):
    """True for a zip archive (torch's format), False for a legacy pickle; AmfeError when
    ``path`` is neither but, say, an HDF5 bed or data set or a text file: named for what it
    is, not "pickled objects"."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
    except OSError as exc:
        raise AmfeError(f"cannot read model file {path}: {exc.strerror}") from None
    if head.startswith(b"PK\x03\x04") or head[:1] == b"\x80":
        return head[:1] == b"P"
    if head == b"\x89HDF\r\n\x1a\n":
        what = "an HDF5 file (a bed or a data set?), not a model"
    elif not head:
        what = "empty"
    else:
        what = "not a plain amfe checkpoint (a torch checkpoint is a zip archive)"
    raise AmfeError(f"model file {path} is {what}; give the .pt file that "
                    "amfe train wrote")


def load_checkpoint(path, arrays=False):
    """The checkpoint dict at ``path``, read with weights_only=True and validated.

    AmfeError for a missing file, a file torch cannot read, a file that holds
    pickled Python objects other than plain data (refused, never executed),
    and a dict that is not an amfe surrogate checkpoint. ``arrays``: read it
    without torch (amfe.training.torchfile), its tensors as numpy arrays
    (TensorArray), with the same refusals: what the numpy inference of the
    multi-scale network (amfe.training.npnet) takes.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise AmfeError(f"model file {path} is a directory; give the .pt file (amfe train -o)")
    if not os.path.isfile(path):
        raise AmfeError(f"model file {path} does not exist")
    zipped = _check_signature(path)
    try:
        ckpt = _read(path, arrays, zipped)
    except pickle.UnpicklingError as exc:
        raise AmfeError(f"amfe refuses to load {path}: it holds pickled Python objects that a "
                        f"weights-only load will not execute ({_unpickler_reason(exc)}); not a "
                        "plain amfe checkpoint") from None
    except Exception as exc:  # noqa: BLE001 - a damaged or foreign file, reported the same way
        raise AmfeError(f"cannot read {path} as a model ({type(exc).__name__}: "
                        f"{str(exc).splitlines()[0] if str(exc) else ''}); not a plain amfe "
                        "checkpoint") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise AmfeError(f"{path} is not a plain amfe checkpoint (no format {FORMAT!r})")
    version = ckpt.get("format_version", -1)
    if type(version) is not int:
        raise AmfeError(f"{path}: format_version must be an integer, got {version!r}")
    if version > FORMAT_VERSION:
        raise AmfeError(f"{path} has checkpoint format version {ckpt['format_version']}; this "
                        f"amfe reads up to {FORMAT_VERSION}: update amfe")
    missing = [k for k in REQUIRED if k not in ckpt]
    if missing:
        raise AmfeError(f"{path} is not a complete amfe checkpoint: missing {', '.join(missing)}")
    if not isinstance(ckpt["arch"], str) or ckpt["arch"] not in ARCH_NAMES:
        raise AmfeError(f"{path}: unknown architecture {ckpt['arch']!r}")
    if not isinstance(ckpt["members"], list) or not ckpt["members"]:
        raise AmfeError(f"{path}: the checkpoint holds no network weights")
    check_fields(ckpt, path)
    return ckpt


def _read(path, arrays, zipped):
    """What ``torch.save`` wrote to ``path`` (``zipped``: a zip archive, else a bare pickle):
    weights-only torch.load, or without torch."""
    if arrays:
        return read_torch_file(path) if zipped else read_pickle(path)
    import torch
    return torch.load(path, map_location="cpu", weights_only=True)


def _unpickler_reason(exc):
    """The line of torch's weights-only error that names the refused object."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    for ln in lines:
        if "WeightsUnpickler error" in ln:
            return ln.split("Please use")[0].strip()
    return lines[0] if lines else type(exc).__name__


def build_members(ckpt, path="checkpoint"):
    """The ensemble's networks, weights loaded, in eval mode (AmfeError for junk weights)."""
    _require_dict(ckpt)
    import torch

    from amfe.training.nets import build_net
    check_members(ckpt, path)
    nets = []
    for k, state in enumerate(ckpt["members"]):
        net = build_net(ckpt["arch"], ckpt["image_shape"], ckpt["arch_args"])
        try:   # numpy weights (load_checkpoint with arrays) become tensors
            net.load_state_dict({name: torch.as_tensor(v) for name, v in state.items()})
        except RuntimeError as exc:
            raise AmfeError(f"{path}: the weights of member {k} do not fit a {ckpt['arch']} net "
                            f"for images {tuple(ckpt['image_shape'])}: "
                            f"{str(exc).splitlines()[0]}") from None
        net.eval()
        nets.append(net)
    return nets


def _require_dict(ckpt):
    """AmfeError unless ``ckpt`` is a dict (amfe.Surrogate("model.pt"): a TypeError deep
    inside otherwise)."""
    if not isinstance(ckpt, dict):
        raise AmfeError(f"amfe.Surrogate takes a checkpoint dict, got {type(ckpt).__name__} "
                        f"{ckpt!r:.80}; read a model file with amfe.Surrogate.load(path)")


BACKENDS = ("auto", "numpy", "torch")


def backend_for(ckpt, backend):
    """The backend that runs ``ckpt``'s networks: "numpy" or "torch" (``backend`` "auto",
    "numpy" or "torch"; see amfe.training.predict.Surrogate)."""
    if backend not in BACKENDS:
        raise AmfeError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    numpy_ok = isinstance(ckpt, dict) and ckpt.get("arch") == "multiscale" \
        and ckpt.get("head") != STIFFNESS_HEAD
    if backend == "numpy" and not numpy_ok:
        raise AmfeError(f"the numpy backend runs six-constant multiscale models; this one is "
                        f"{ckpt.get('arch') if isinstance(ckpt, dict) else ckpt!r}: use "
                        "backend='torch'")
    return "numpy" if backend == "numpy" or (backend == "auto" and numpy_ok) else "torch"


def numpy_members(ckpt, path="checkpoint"):
    """The ensemble's multi-scale networks for numpy inference (amfe.training.npnet), weights
    checked as :func:`build_members` checks them."""
    from amfe.training.npnet import NumpyMultiScale
    _require_dict(ckpt)
    check_members(ckpt, path)
    return [NumpyMultiScale(state, ckpt["image_shape"], ckpt["arch_args"])
            for state in ckpt["members"]]


def check_image_shape(ckpt, shape, what="the image", path="the model", bed=False):
    """AmfeError naming both shapes unless ``shape`` (layers, H, W) is the checkpoint's.

    ``bed``: the image is a bed's, so the message also says how to make a bed
    of the model's scale.
    """
    want = tuple(int(s) for s in ckpt["image_shape"])
    got = tuple(int(s) for s in shape)
    if got != want:
        scale = ckpt.get("pixelation", {}).get("scale")
        fix = "use a model trained on this image shape"
        if bed and isinstance(scale, str):
            fix += f", or a bed of the model's scale (`amfe pack --scale {scale}`)"
        raise AmfeError(f"{what} has shape {'x'.join(map(str, got))} but {path} was trained on "
                        f"images of shape {'x'.join(map(str, want))} (scale {scale}); {fix}")


def model_springs(ckpt) -> dict:
    """The bond springs of a model's labels: {"name": "paper"} or the continuum springs'
    record with their values (docs/model.md, section 11), from its data set's ``springs``
    attribute. A model trained before data sets recorded their springs: the paper's."""
    record = (ckpt.get("dataset") or {}).get("springs")
    if isinstance(record, str):
        record = json.loads(record)
    return dict(record) if record else {"name": "paper"}


def describe(ckpt, path, n_members, inputs) -> str:
    """A surrogate in one line: the file, the networks, what they read, the size and
    material trained on, and the sizes with calibrated intervals."""
    px, m = ckpt.get("pixelation") or {}, ckpt.get("material") or {}
    size = " x ".join(f"{1e3 * v:g}" for v in px.get("bed_size", ())) or "?"
    conformal = ckpt.get("conformal") or {}
    sizes = ", ".join(conformal.get("sizes", {})) or "none"
    coverage = (f"{100 * conformal['coverage']:g} % intervals at {sizes} mm" if conformal
                else "no calibrated intervals")
    return (f"Surrogate({os.path.basename(os.fspath(path))}: {n_members} x {ckpt.get('arch')} "
            f"reading {', '.join(inputs)}; trained on {size} mm beds, E "
            f"{m.get('E', float('nan')) / 1e9:g} GPa, nu {m.get('nu')}, psi {m.get('psi')}, "
            f"{model_springs(ckpt)['name']} springs; {coverage})")
