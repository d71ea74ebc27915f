"""Inference: a checkpoint's ensemble on images or beds, with the out-of-distribution flag.

:class:`Surrogate` holds the members of one checkpoint (a single network is
an ensemble of one). Each member's prediction is optionally averaged over the
bed's symmetric images (test-time augmentation, ``tta`` in the checkpoint:
the four mirror images, or all eight symmetries of the square with the
labels of the x<->y swapped ones mapped back), in Pa and -. The ensemble
mean is the prediction; the spread per property is the members' standard
deviation over |mean| (relative); the flag score is max over properties of
(relative spread / that property's median relative spread on the
validation beds), and a bed is flagged when the score exceeds the
checkpoint's threshold (the 95th percentile of the score on the validation
beds, so about 1 in 20 in-distribution beds is flagged).

A second, input-side check needs no ensemble: the fill of a bed's fullest
cells (:func:`fill_statistic`, the 99th percentile of its pixels) measures
the sintering enlargement, i.e. the neck size the moduli hang on, and the
spread misses beds made with other enlargements (docs/surrogate_diagnosis.md).
A checkpoint with a ``fill_range`` (the 0.5th and 99.5th percentiles of that
statistic over its training beds, :func:`calibrate_fill`) flags a bed whose
fill lies outside it, whatever the spread.
"""
import math
import os
import time
from pathlib import Path

import numpy as np

import amfe.version
from amfe.dataset.bondimage import bond_image
from amfe.dataset.images import pixelate
from amfe.errors import AmfeError
from amfe.model.carrying import rule1_factor
from amfe.training.checkpoint import (
    backend_for,
    build_members,
    check_image_shape,
    describe,
    load_checkpoint,
    model_springs,
    numpy_members,
)
from amfe.training.ensemble import symmetries, tta_mode
from amfe.training.fillcheck import fill_shift, fill_statistic
from amfe.training.imagebox import sample_spacing
from amfe.training.inputs import DEFAULT_INPUTS, check_inputs, image_array
from amfe.training.npnet import predict_raw as predict_numpy
from amfe.training.shipped import models_dir, shipped_model_for, unrecorded_size
from amfe.training.stiffness_predict import is_stiffness, member_constants, summarize
from amfe.vocab import LABEL_NAMES

DEFAULT_MODEL_NAME = "multiscale_small.pt"
TRAIN_HINT = ("train it with the commands of docs/model_card.md (`amfe train` per member, "
              "then `run/train/merge_members.py`) or pass --model MODEL.pt from `amfe train`")


def default_model_path():
    """The model shipped in the package: amfe/models/multiscale_small.pt (docs/model_card.md)."""
    return Path(amfe.version.__file__).resolve().parent / "models" / DEFAULT_MODEL_NAME


class Surrogate:
    """The networks, normalisation and flag threshold of one checkpoint.

    ``backend``: "numpy" runs the multi-scale network's inference in numpy
    (amfe.training.npnet: no torch import, 2.5-4 s less start-up; the same
    predictions to float32 rounding), "torch" in torch (a GPU, or large batches:
    about 3x faster a bed); "auto" is numpy for a six-constant multi-scale
    checkpoint (every shipped six-constant model), torch for any other.
    """

    def __init__(self, ckpt: dict, path: str = "model", backend: str = "auto") -> None:
        self.ckpt = ckpt
        self.path = os.fspath(path)
        self.backend = backend_for(ckpt, backend)
        self._nets = None
        if self.backend == "numpy":
            self._numpy_nets = numpy_members(ckpt, self.path)
        else:
            self._numpy_nets = None
            _ = self.nets   # built now: junk weights are refused at load
        self.image_shape = tuple(int(s) for s in ckpt["image_shape"])
        self.inputs = check_inputs(ckpt.get("inputs", DEFAULT_INPUTS))
        self.n_fill = self.image_shape[0] // len(self.inputs)   # the fill layers come first
        self.tta = tta_mode(ckpt.get("tta", "none"))
        spread = ckpt.get("spread") or {}
        self.spread_scale = np.asarray(spread.get("scale", np.ones(6)), np.float64)
        self.threshold = spread.get("threshold")
        self.fill_range = ckpt.get("fill_range")
        # A checkpoint without "label_rule" was trained on label rule 1 (V = hull of the
        # largest piece's centres); its moduli are converted to rule 2 (V = the bed's box)
        # per bed in predict_bed (docs/model_card.md, docs/model.md section 5).
        self.label_rule = int(ckpt.get("label_rule", 1))
        self.springs = model_springs(ckpt)   # the labels' bond springs (docs/model.md, s. 11)
        self.labels = ("label rule 2" if self.label_rule >= 2 else
                       "trained on label rule 1, converted to rule 2 (moduli x V_hull / V_box)")

    @classmethod
    def load(cls, path: str | os.PathLike | None = None, backend: str = "auto") -> "Surrogate":
        if path is None:
            path = default_model_path()
            if not path.is_file():
                raise AmfeError(f"the default model {path} is not installed; {TRAIN_HINT}")
        # Read without torch (its tensors as numpy arrays) unless torch runs the networks.
        return cls(load_checkpoint(path, arrays=backend != "torch"), path, backend)

    @property
    def nets(self) -> list:
        """The members as torch modules in eval mode (built when first asked for)."""
        if self._nets is None:
            import torch
            self._nets = build_members(self.ckpt, self.path)
            for net in self._nets:
                # Channels-last activations: faster, with the same results to rounding
                # (docs/benchmarks.md, "Figures quoted in the code").
                net.to(memory_format=torch.channels_last)
        return self._nets

    @property
    def norm(self) -> object:
        """The labels' torch Normalizer (amfe.training.data), for the torch networks."""
        from amfe.training.data import Normalizer
        return Normalizer.from_dict(self.ckpt["normalizer"])

    @property
    def n_members(self) -> int:
        return len(self.ckpt["members"])

    def __repr__(self) -> str:
        return describe(self.ckpt, self.path, self.n_members, self.inputs)[:-1] \
            + f"; runs in {self.backend})"

    def member_outputs(self, images: np.ndarray, batch_size: int | None = None) -> np.ndarray:
        """Raw predictions of every member, float64 array (members, n, 6)."""
        return self.run_members(image_array(images, self.ckpt, self.path), batch_size)

    def run_members(self, x: np.ndarray, batch_size: int | None = None) -> np.ndarray:
        """:meth:`member_outputs` of inputs x (n, channels, H, W) float32 whose H x W is not
        checked: the size rule reads beds of other sizes with a fully convolutional model."""
        if self.backend == "numpy":
            syms = symmetries(self.tta, x.shape[-1] == x.shape[-2])
            return np.stack([predict_numpy(net, x, self.ckpt["normalizer"], syms, batch_size)
                             for net in self._numpy_nets])
        import torch

        from amfe.training.ensemble import predict_raw
        x = torch.as_tensor(x)
        if is_stiffness(self.ckpt):   # the six constants of each member's C
            return member_constants(self, x, batch_size)
        out, norm = np.empty((self.n_members, x.shape[0], 6)), self.norm
        for k, net in enumerate(self.nets):
            out[k] = predict_raw(net, x, norm, self.tta, batch_size).numpy()
        return out

    def predict(self, images: "np.ndarray | str | os.PathLike | object | list",
                batch_size: int | None = None, fill_shift: "float | np.ndarray" = 0.0) -> dict:
        """Predict the six constants of beds or of their images.

        ``images``: a :class:`~amfe.model.bed.Bed`, a bed file's path, a list of
        them (a batch: row k is bed k), or inputs (n, channels, H, W) (the
        image kinds of ``self.inputs`` stacked). Returns {mean (n, 6), spread
        (n, 6) relative, score (n,), fill (n,), fill_out (n,) bool, nonfinite
        (n,) bool, flagged (n,) bool}, the six in label order (Ex, Ey, Ez [Pa],
        nu_yz, nu_xz, nu_xy); flagged = spread over the threshold, fill_out, or
        a member's prediction not finite (NaN, inf). ``fill_shift`` (scalar or (n,)): how
        much higher the fill statistic reads at the images' sampling than at the training's
        (:meth:`fill_shift_of`; beds get theirs), subtracted before the range check.
        """
        if _is_bed(images):
            bed = _read(images)
            _check_shipped_size(bed, self.path)
            return self.predict_bed(bed)[0]
        if isinstance(images, (list, tuple)) and any(_is_bed(b) for b in images):
            if not all(_is_bed(b) for b in images):
                raise AmfeError("predict takes a bed, a bed file, a list of those, or an image "
                                "array; got a list mixing beds with other things")
            beds = [_read(b) for b in images]
            images = np.stack([self.inputs_of(b)[0] for b in beds])
            fill_shift = np.array([self.fill_shift_of(b) for b in beds])
        res = summarize(self, images, batch_size)   # a stiffness head: also C, nine constants
        x = np.asarray(images)
        res["fill"] = fill_statistic((x[None] if x.ndim == 3 else x)[:, :self.n_fill]) \
            - fill_shift
        if self.fill_range:
            res["fill_out"] = ((res["fill"] < self.fill_range["lo"])
                               | (res["fill"] > self.fill_range["hi"]))
        else:
            res["fill_out"] = np.zeros(len(res["fill"]), bool)
        res["flagged"] = res["flagged"] | res["fill_out"]
        return res

    def fill_shift_of(self, bed: object) -> float:
        """How much higher the fill statistic reads on ``bed``'s image than at the training's
        sampling (amfe.training.fillcheck.fill_shift: 0 but for a bed imaged coarser)."""
        px = self.ckpt["pixelation"]
        return fill_shift(_image_size(bed, self.ckpt), px["image_cell"], px["image_spacing"])

    def inputs_of(self, bed: object) -> tuple:
        """The network input of ``bed``, imaged as the training data was.

        Returns (inputs (channels, H, W) float32: the image kinds of
        ``self.inputs`` stacked, volume-fraction image (layers, H, W), seconds
        {pixelate, bonds (when the model reads bond images)}).
        """
        t0 = time.perf_counter()
        image = pixelate_like_training(bed, self.ckpt, self.path)
        t1 = time.perf_counter()
        times = {"pixelate": t1 - t0}
        parts = {"fill": image}
        if "bonds" in self.inputs:
            parts["bonds"] = bond_image_like_training(bed, self.ckpt)
            times["bonds"] = time.perf_counter() - t1
        return np.concatenate([parts[k] for k in self.inputs], axis=0), image, times

    def predict_beds(self, beds: list) -> list:
        """:meth:`predict_bed` of several beds with their images in one batch.

        Returns a list of (result dict with rows of length 1, image, seconds) per
        bed, equal to one-at-a-time :meth:`predict_bed` calls up to the
        floating-point order of a batched forward pass; "predict" is the
        batch's network time shared evenly.
        """
        if len(beds) == 1:
            return [self.predict_bed(beds[0])]
        made = [self.inputs_of(bed) for bed in beds]
        t = time.perf_counter()
        x = np.stack([x for x, _, _ in made])
        shifts = np.array([self.fill_shift_of(bed) for bed in beds])
        res = self._with_bonds(self.predict(x, fill_shift=shifts), x)
        if self.label_rule < 2:
            for k, bed in enumerate(beds):
                res["mean"][k, :3] *= rule1_factor(bed.centers, bed.radii, bed.attrs.get("size"))
        share = (time.perf_counter() - t) / len(beds)
        return [({key: v[k:k + 1] for key, v in res.items()}, image, {**times, "predict": share})
                for k, (_, image, times) in enumerate(made)]

    def predict_bed(self, bed: object) -> tuple:
        """Image ``bed`` as the training data was and predict (label rule 2: the moduli
        of a rule-1 checkpoint are converted with the bed's own volumes).

        Returns (result dict, volume-fraction image (layers, H, W), seconds
        {pixelate, bonds (when the model reads bond images), predict}); the result holds
        the bond image too ("bond_image", (1, layers, H, W)) when the model reads one.
        """
        x, image, times = self.inputs_of(bed)
        t2 = time.perf_counter()
        res = self._with_bonds(self.predict(x[None], fill_shift=self.fill_shift_of(bed)),
                               x[None])
        if self.label_rule < 2:   # rule-1 moduli -> rule 2; spread is relative, unchanged
            res["mean"][:, :3] *= rule1_factor(bed.centers, bed.radii, bed.attrs.get("size"))
        times["predict"] = time.perf_counter() - t2
        return res, image, times

    def _with_bonds(self, res, x):
        """``res`` with "bond_image" (n, layers, H, W), the bond layers of the inputs x, when
        the model reads them (the flag's risk features read them too: made once a bed)."""
        if "bonds" in self.inputs:
            k = self.inputs.index("bonds")
            res["bond_image"] = x[:, k * self.n_fill:(k + 1) * self.n_fill]
        return res


def _is_bed(item):
    """True for what :meth:`Surrogate.predict` takes as one bed: a Bed or a bed file's path."""
    return isinstance(item, (str, os.PathLike)) or hasattr(item, "centers")


def _check_shipped_size(bed, path):
    """AmfeError naming amfe.predict when ``path`` is a shipped model and another shipped one
    is the bed's (Surrogate.load() loads the small one; amfe.predict picks by size)."""
    if Path(path).resolve().parent != models_dir():
        return
    want = shipped_model_for(bed, stiffness=Path(path).name.startswith("stiffness"))
    if Path(want).resolve() != Path(path).resolve():
        raise AmfeError(f"{Path(path).name} is not the shipped model for this bed's size "
                        f"({Path(want).name} is): use amfe.predict(bed), which picks it")


def _read(item):
    if isinstance(item, (str, os.PathLike)):
        from amfe.io.bedfile import read_bed  # h5py (0.02 s) only for a bed read from a file

        return read_bed(item)
    return item


def pixelate_like_training(bed, ckpt, path="the model"):
    """The image of ``bed`` made as the training data's (cells, layers, sample spacing; a bed
    of over a million sample lines at twice the spacing: amfe.training.imagebox.sample_spacing).

    The box is [0, the bed's recorded size] when it records one (generated
    beds), else [0, the training beds' size]. AmfeError if the image's shape
    is not the model's.
    """

    px = ckpt["pixelation"]
    size = _image_size(bed, ckpt)
    r_max = float(np.max(bed.radii))
    if r_max > max(size):   # pixelate would size its sample blocks by it (docs/model.md, sec. 6)
        raise AmfeError(f"the bed has a particle of radius {r_max:g} m, larger than the imaged "
                        f"box ({_mm(size)} mm): not a bed {path} can predict")
    n_kinds = len(check_inputs(ckpt.get("inputs", DEFAULT_INPUTS)))
    _check_grid(size, px, n_kinds, ckpt, path)
    image = pixelate(bed, cell=tuple(px["image_cell"][:2]),
                     layer_thickness=float(px["layer_thickness"]), box=((0.0, 0.0, 0.0), size),
                     spacing=sample_spacing(size, px["image_cell"], px["image_spacing"]))
    shape = (image.shape[0] * n_kinds, *image.shape[1:])
    check_image_shape(ckpt, shape, f"the bed's image ({_mm(size)} mm)", path, bed=True)
    return np.asarray(image, np.float32)


def bond_image_like_training(bed, ckpt):
    """The bond-stiffness image of ``bed`` (amfe.dataset.bondimage) on the training data's grid."""

    px = ckpt["pixelation"]
    return bond_image(bed, cell=tuple(px["image_cell"][:2]),
                      layer_thickness=float(px["layer_thickness"]),
                      box=((0.0, 0.0, 0.0), _image_size(bed, ckpt)))


def _check_grid(size, px, n_kinds, ckpt, path):
    """Refuse a bed whose image would be far from the model's shape before pixelating it.

    A bed that records a size of 1 m would otherwise be pixelated on a grid of
    ~10^10 samples before the shapes are compared. The count here is the
    number of whole cells (layers) the box holds; the exact comparison
    follows the pixelation.
    """
    cells = [size[0] / float(px["image_cell"][0]), size[1] / float(px["image_cell"][1]),
             size[2] / float(px["layer_thickness"])]
    layers, h, w = (max(1, math.ceil(c - 1e-9)) for c in (cells[2], cells[1], cells[0]))
    want = tuple(int(s) for s in ckpt["image_shape"])
    if abs(layers * n_kinds - want[0]) > 1 or abs(h - want[1]) > 1 or abs(w - want[2]) > 1:
        check_image_shape(ckpt, (layers * n_kinds, h, w), f"the bed's image ({_mm(size)} mm)",
                          path, bed=True)


def _image_size(bed, ckpt):
    """The imaged box's size [m]: the bed's recorded size, else its spheres' bounding box
    from the origin cut to whole cells in x and y (training/anysize.py) and the training
    beds' height."""
    size = bed.attrs.get("size") if hasattr(bed, "attrs") else None
    if size is None:
        size = unrecorded_size(bed, ckpt["pixelation"]["image_cell"],
                               ckpt["pixelation"]["bed_size"][2])
    try:
        out = tuple(float(s) for s in size)
    except (TypeError, ValueError):
        out = ()
    if len(out) != 3 or not all(math.isfinite(s) and s > 0 for s in out):
        raise AmfeError(f"the bed's size attribute must be three positive lengths in m, got "
                        f"{size!r}; fix or remove it (the box is then the training beds')")
    return out


def _mm(size):
    return " x ".join(f"{float(s) * 1e3:g}" for s in size)


def check_material(bed, ckpt, path="the model"):
    """The factor E_bed / E_model the predicted moduli are scaled by (1.0: the model's material).

    A bed that differs from the model's material only in E is predicted by scaling (every
    spring is E times a function of a*, R, nu and psi, docs/model.md); another nu or psi is
    refused (AmfeError) until the network reads them."""
    want = ckpt.get("material")
    if not want:
        return 1.0
    try:
        have = bed.material().asdict()
    except (TypeError, ValueError) as exc:   # material attributes of the wrong type
        raise AmfeError(f"the bed's material attributes are not numbers ({exc}); fix or remove "
                        "material_E, material_nu, material_psi, material_density") from None
    off = [k for k in ("E", "nu", "psi") if abs(float(have[k]) - float(want[k]))
           > 1e-9 * max(1.0, abs(float(want[k])))]
    if off == ["E"]:   # every spring is E x f(a*, R, nu, psi): the moduli scale exactly with E
        return float(have["E"]) / float(want["E"])
    if off:
        raise AmfeError(f"the bed's particles ({', '.join(f'{k}={have[k]:g}' for k in off)}) are "
                        f"not the material {path} was trained on "
                        f"({', '.join(f'{k}={float(want[k]):g}' for k in off)}); nu and psi "
                        "inputs are coming (issue 46): solve it with amfe homogenize")
    return 1.0


def as_properties(row):
    """A (6,) prediction as {Ex, Ey, Ez, nu_yz, nu_xz, nu_xy} floats."""
    return {name: float(v) for name, v in zip(LABEL_NAMES, row)}
