"""Data for the surrogate: a lazy torch Dataset over an amfe data-set file, splits, normalisation.

The file layout is :mod:`amfe.dataset.datafile` (``images`` (M, layers, H, W)
float32, ``labels`` (M, 6) Ex, Ey, Ez [Pa], nu_yz, nu_xz, nu_xy, ``status``
(M,) 0 ok / 1 failed). Only rows with status 0 and finite labels are used.

A network's input stacks one or more image kinds along the channel axis
(:data:`INPUT_KINDS`): "fill", the volume-fraction image (the paper's), and
"bonds", the bond-stiffness image (:mod:`amfe.dataset.bondimage`); inputs ("fill",
"bonds") give (2 layers, H, W) channels, the fill layers first.

- :class:`BedDataset` opens the HDF5 file lazily, once per process (an h5py
  handle must not cross a fork), so a DataLoader with several workers works;
  ``in_memory=True`` reads the selected rows in one go on first use instead
  (what training does when they fit in memory: a ``small`` set of 2 000 beds
  is 10 MB).
- :func:`split_indices`: the paper's 80/20 train/validation split, a
  permutation drawn from ``numpy.random.default_rng(seed)``, the same for a
  given (rows, seed) on any machine. The held-out test set is a separate file
  made with another data-set seed.
- :class:`Normalizer`: per-label standardisation, optionally of log(label)
  (the moduli span 14-400 GPa: in log space an error is a relative error);
  its mean/std/log travel in the checkpoint as plain lists.
- :func:`dataset_hash`: sha256 of the used rows' images and labels, stored in
  the checkpoint so a model names the data it was trained on.
- Label-preserving symmetries (:func:`augment_batch`, :func:`flip_images`,
  :func:`transpose_labels`): mirroring x or y leaves all six orthotropic
  constants unchanged; swapping x and y maps (Ex, Ey, Ez, nu_yz, nu_xz,
  nu_xy) to (Ey, Ex, Ez, nu_xz, nu_yz, nu_yx) with nu_yx = nu_xy Ey / Ex
  (nu_ij = -S_ji / S_ii, amfe.model.averages), an involution.
"""
import hashlib
import os

import numpy as np
import torch

from amfe.dataset.datafile import DATA_SET_FIX
from amfe.dataset.parts import STATUS_OK
from amfe.errors import AmfeError
from amfe.io.h5damage import damaged
from amfe.training import AUGMENTATIONS
from amfe.training.inputs import DEFAULT_INPUTS, INPUT_KINDS, check_inputs, image_array
from amfe.vocab import LABEL_NAMES


def _damaged(path):
    """A damaged chunk of the data set ``path`` read below: one AmfeError line (issue 45)."""
    return damaged(path, "data set", DATA_SET_FIX)

# Root attributes of a data set that say how its images were made (amfe.dataset.datafile).
IMAGE_ATTRS = ("scale", "image_shape", "image_cell", "layer_thickness", "image_spacing",
               "bed_size", "seed", "count", "format_version", "springs")


def _require_inputs(f, path, inputs):
    for kind in inputs:
        name = INPUT_KINDS[kind]
        if name not in f:
            hint = (f"; add it with `amfe dataset --add-bond-images {path}`"
                    if name == "bond_images" else "")
            raise AmfeError(f"{path} has no /{name}, which inputs {','.join(inputs)} need{hint}")
        if f[name].shape != f["images"].shape:
            raise AmfeError(f"{path}: /{name} has shape {f[name].shape}, /images "
                            f"{f['images'].shape}")


def _open(path):
    import h5py  # noqa: PLC0415 (heavy or optional: loaded when used)
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise AmfeError(f"data set {path} does not exist")
    if not h5py.is_hdf5(path):
        raise AmfeError(f"{path} is not an HDF5 file")
    with _damaged(path):
        f = h5py.File(path, "r")
    for name in ("images", "labels", "status"):
        if name not in f:
            f.close()
            raise AmfeError(f"{path} is not an amfe data set: no /{name} "
                            "(see amfe.dataset.datafile)")
    if f["images"].ndim != 4 or f["labels"].shape[1:] != (6,):
        shape_i, shape_l = f["images"].shape, f["labels"].shape
        f.close()
        raise AmfeError(f"{path}: /images must be (M, layers, H, W) and /labels (M, 6), got "
                        f"{shape_i} and {shape_l}")
    return f


def _plain(value):
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


def dataset_info(path, inputs=DEFAULT_INPUTS):
    """Rows usable for training and the file's image attributes.

    Returns {path, n_rows, ok (int64 array of row numbers with status 0 and
    finite labels), ok_nonfinite (those with status 0 but a non-finite label:
    a corrupt record, which training refuses), image_shape [channels, H, W] of the network input
    (channels = layers x number of input kinds), inputs, and the root
    attributes in :data:`IMAGE_ATTRS` that exist, as plain Python values}.
    AmfeError if the file lacks an image kind of ``inputs``.
    """
    inputs = check_inputs(inputs)
    with _open(path) as f, _damaged(path):
        _require_inputs(f, path, inputs)
        status = f["status"][()]
        labels = f["labels"][()]
        finite = np.all(np.isfinite(labels), axis=1)
        ok = np.flatnonzero((status == STATUS_OK) & finite)
        layers, H, W = (int(s) for s in f["images"].shape[1:])
        info = {"path": os.fspath(path), "n_rows": int(status.shape[0]), "ok": ok,
                "ok_nonfinite": np.flatnonzero((status == STATUS_OK) & ~finite),
                "image_shape": [layers * len(inputs), H, W], "inputs": list(inputs)}
        for key in IMAGE_ATTRS:
            if key in f.attrs and key != "image_shape":
                info[key] = _plain(f.attrs[key])
    return info


def read_rows(path, rows=None, inputs=DEFAULT_INPUTS):
    """(images float32 (n, channels, H, W), labels float64 (n, 6)) of ``rows`` (default: all ok).

    The images stack the kinds of ``inputs`` along the channel axis.
    """
    inputs = check_inputs(inputs)
    if rows is None:
        rows = dataset_info(path, inputs)["ok"]
    rows = np.asarray(rows, np.int64)
    with _open(path) as f, _damaged(path):
        _require_inputs(f, path, inputs)
        # h5py wants increasing indices; read sorted, then restore the order asked for.
        order = np.argsort(rows, kind="stable")
        srt = rows[order]
        uniq, inv = np.unique(srt, return_inverse=True)
        images = np.concatenate(
            [f[INPUT_KINDS[k]][uniq] if uniq.size else np.zeros((0, *f["images"].shape[1:]))
             for k in inputs], axis=1)
        labels = f["labels"][uniq] if uniq.size else np.zeros((0, 6))
    out_i = np.empty((rows.size, *images.shape[1:]), np.float32)
    out_l = np.empty((rows.size, 6), np.float64)
    out_i[order], out_l[order] = images[inv], labels[inv]
    return out_i, out_l


def dataset_hash(path, rows=None, inputs=DEFAULT_INPUTS):
    """sha256 (hex) of the input images (float32) and labels (float64) of ``rows`` (default ok)."""
    images, labels = read_rows(path, rows, inputs)
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(images, np.float32).tobytes())
    h.update(np.ascontiguousarray(labels, np.float64).tobytes())
    return h.hexdigest()


def split_indices(rows, val_fraction=0.2, seed=0):
    """(train, validation) row numbers: a seeded permutation of ``rows``, the last part validation.

    ``val_fraction`` 0.2 is the paper's 1 600 / 400 split of 2 000 beds.
    Deterministic in (rows, val_fraction, seed).
    """
    rows = np.asarray(rows, np.int64)
    if not (0.0 <= val_fraction < 1.0):
        raise AmfeError(f"validation fraction must lie in [0, 1), got {val_fraction}")
    perm = rows[np.random.default_rng(seed).permutation(rows.size)]
    n_val = int(round(val_fraction * rows.size))
    if rows.size - n_val < 1:
        raise AmfeError(f"{rows.size} usable record(s) leave nothing to train on")
    return np.sort(perm[:rows.size - n_val]), np.sort(perm[rows.size - n_val:])


class BedDataset(torch.utils.data.Dataset):
    """(image float32 (channels, H, W), labels float64 (6,)) of selected rows of a data-set file.

    Lazy: the file is opened on first access in each process (so the Dataset
    can be handed to DataLoader workers, each opening its own handle), and
    each item reads one image chunk. ``in_memory=True`` reads all selected
    rows at the first access instead. ``rows`` default: every ok row;
    ``inputs``: the image kinds stacked (:data:`INPUT_KINDS`).
    """

    def __init__(self, path, rows=None, in_memory=False, inputs=DEFAULT_INPUTS):
        self.path = os.fspath(path)
        self.inputs = check_inputs(inputs)
        info = dataset_info(self.path, self.inputs)
        self.rows = info["ok"] if rows is None else np.asarray(rows, np.int64)
        bad = np.setdiff1d(self.rows, info["ok"])
        if bad.size:
            raise AmfeError(f"{self.path}: rows {bad[:5].tolist()} are failed records or out of "
                            "range")
        self.image_shape = tuple(info["image_shape"])
        self.in_memory = bool(in_memory)
        self._file = None
        self._pid = None
        self._cache = None

    def __len__(self):
        return int(self.rows.size)

    def _handle(self):
        if self._file is None or self._pid != os.getpid():
            self._file = _open(self.path)   # a fresh handle in each (forked) worker
            self._pid = os.getpid()
        return self._file

    def arrays(self):
        """All selected rows as (images, labels) numpy arrays (read once, then cached)."""
        if self._cache is None:
            self._cache = read_rows(self.path, self.rows, self.inputs)
        return self._cache

    def __getitem__(self, k):
        if self.in_memory:
            images, labels = self.arrays()
            return torch.from_numpy(images[k]), torch.from_numpy(labels[k])
        f = self._handle()
        row = int(self.rows[k])
        with _damaged(self.path):
            image = np.concatenate([np.asarray(f[INPUT_KINDS[kind]][row], np.float32)
                                    for kind in self.inputs], axis=0)
            label = np.asarray(f["labels"][row], np.float64)
        return torch.from_numpy(image), torch.from_numpy(label)

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_file"], state["_pid"] = None, None   # never pickle an open h5py handle
        return state


class Normalizer:
    """Per-label standardisation z = (f(y) - mean) / std, f = log for the labels marked ``log``."""

    def __init__(self, mean, std, log):
        self.mean = torch.as_tensor(np.asarray(mean, np.float64))
        self.std = torch.as_tensor(np.asarray(std, np.float64))
        self.log = torch.as_tensor(np.asarray(log, bool))
        if self.mean.shape != (6,) or self.std.shape != (6,) or self.log.shape != (6,):
            raise AmfeError("a normaliser needs six means, six stds and six log flags")
        if not torch.all(self.std > 0):
            raise AmfeError(f"normaliser stds must be positive, got {self.std.tolist()}")

    @staticmethod
    def nonpositive_logs(labels, log):
        """'name (min v), ...' of the labels marked ``log`` (6,) with a value <= 0 in
        ``labels`` (n, 6); "" when there is none."""
        labels = np.asarray(labels, np.float64)
        bad = np.asarray(log, bool) & np.any(labels <= 0, axis=0)
        return ", ".join(f"{LABEL_NAMES[k]} (min {labels[:, k].min():.3g})"
                         for k in np.flatnonzero(bad))

    @classmethod
    def fit(cls, labels, log=(True, True, True, False, False, False)):
        labels = np.asarray(labels, np.float64)
        log = np.asarray(log, bool)
        names = cls.nonpositive_logs(labels, log)
        if names:
            raise AmfeError(f"log normalisation of a label with non-positive values: {names}; "
                            "train it in linear space")
        f = np.where(log, np.log(np.where(log, labels, 1.0)), labels)
        std = f.std(axis=0)
        return cls(f.mean(axis=0), np.where(std > 0, std, 1.0), log)

    def encode(self, labels):
        """Raw labels (n, 6) -> normalised float32 tensor."""
        y = torch.as_tensor(labels, dtype=torch.float64)
        y = torch.where(self.log, torch.log(torch.where(self.log, y, torch.ones_like(y))), y)
        return ((y - self.mean) / self.std).float()

    def decode(self, z):
        """Normalised outputs (n, 6) -> raw labels, float64 tensor."""
        y = torch.as_tensor(z, dtype=torch.float64) * self.std + self.mean
        return torch.where(self.log, torch.exp(y), y)

    def to_dict(self):
        return {"mean": [float(v) for v in self.mean], "std": [float(v) for v in self.std],
                "log": [bool(v) for v in self.log], "labels": list(LABEL_NAMES)}

    @classmethod
    def from_dict(cls, d):
        return cls(d["mean"], d["std"], d["log"])


# ---------------------------------------------------------------- symmetries

def image_batch(images, ckpt, path="the model"):
    """:func:`amfe.training.inputs.image_array` as a float32 tensor (n, channels, H, W)."""
    return torch.as_tensor(image_array(images, ckpt, path))


def transpose_labels(labels):
    """Labels of the bed with x and y swapped: (Ey, Ex, Ez, nu_xz, nu_yz, nu_xy Ey/Ex)."""
    y = torch.as_tensor(labels)
    return torch.stack([y[:, 1], y[:, 0], y[:, 2], y[:, 4], y[:, 3], y[:, 5] * y[:, 1] / y[:, 0]],
                       dim=1)


def flip_images(images, flip_x=False, flip_y=False, transpose=False):
    """Images mirrored in x (W axis), in y (H axis), then with x and y swapped."""
    x = images
    if flip_x:
        x = x.flip(-1)
    if flip_y:
        x = x.flip(-2)
    if transpose:
        x = x.transpose(-1, -2)
    return x




def augment_batch(images, labels, mode, generator):
    """Random label-preserving symmetries per sample: "flips" (mirror x, y) or "d4" (+ x<->y).

    images (B, layers, H, W), labels raw (B, 6); returns new tensors.
    """
    if mode == "none":
        return images, labels
    if mode not in AUGMENTATIONS:
        raise AmfeError(f"unknown augmentation {mode!r}; choose one of {', '.join(AUGMENTATIONS)}")
    B = images.shape[0]
    r = torch.rand(B, 3, generator=generator)
    fx = (r[:, 0] < 0.5).view(B, 1, 1, 1)
    fy = (r[:, 1] < 0.5).view(B, 1, 1, 1)
    x = torch.where(fx, images.flip(-1), images)
    x = torch.where(fy, x.flip(-2), x)
    if mode == "d4" and x.shape[-1] == x.shape[-2]:
        tr = r[:, 2] < 0.5
        x = torch.where(tr.view(B, 1, 1, 1), x.transpose(-1, -2), x)
        labels = torch.where(tr.view(B, 1), transpose_labels(labels), labels)
    return x, labels
