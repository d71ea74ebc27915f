"""Fine-tuning: members that start from a trained checkpoint's weights (``amfe train --init``).

A trained member has seen its data set many times and overfits it (training
loss a third of the validation loss, docs/surrogate_scaling.md). Beds it has
never seen are the lever, and continuing its training on a fresh data set
costs a few epochs where training from scratch on the union costs the full
schedule. The fine-tuned member keeps everything its outputs are expressed
in: the network and its arguments, the input image kinds and their
pixelation, and the label normalisation (means, standard deviations, log
flags). Only the weights change. Member j of the run starts from the
checkpoint's member ``member + j``; its seed still orders its batches and
augmentation.
"""
import hashlib

import numpy as np

from amfe.errors import AmfeError
from amfe.training.checkpoint import check_image_shape, load_checkpoint
from amfe.training.data import Normalizer


def file_sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def load_init(path, member, n_members):
    """The starting point of a fine-tuning run: the checkpoint ``path``'s members
    ``member`` .. ``member + n_members - 1``.

    Returns {arch, arch_args, inputs, normalizer (Normalizer), states (list of
    state dicts), fill_range, ckpt, record (what the new checkpoint stores of
    its origin)}; AmfeError when it has too few members.
    """
    ckpt = load_checkpoint(path)
    members = ckpt["members"]
    if not (0 <= member and member + n_members <= len(members)):
        raise AmfeError(f"--init {path} has {len(members)} member(s); members {member}.."
                        f"{member + n_members - 1} were asked for (--init-member {member}, "
                        f"--members {n_members})")
    origin = ckpt.get("dataset") or {}
    record = {"path": str(path), "sha256": file_sha256(path), "member": int(member),
              "member_seeds": list(ckpt.get("member_seeds", []))[member:member + n_members],
              "dataset": {k: origin.get(k) for k in ("path", "sha256", "seed", "scale", "n_ok",
                                                     "n_train", "n_validation")},
              "training": {k: (ckpt.get("training") or {}).get(k)
                           for k in ("epochs", "lr", "schedule", "augment", "seed", "init")}}
    return {"arch": ckpt["arch"], "arch_args": dict(ckpt["arch_args"]),
            "inputs": tuple(ckpt["inputs"]), "normalizer": Normalizer.from_dict(ckpt["normalizer"]),
            "states": members[member:member + n_members], "record": record,
            "fill_range": ckpt.get("fill_range"), "ckpt": ckpt}


#: Architectures whose weights read an image of any in-plane size (global pooling before
#: the head): training/multiscale.py, training/anysize.py.
SIZE_FREE_ARCHS = ("multiscale", "anysize")


def check_data(start, data_path, info, pixelation, labels):
    """AmfeError unless the new data set's images and labels are what the initial model reads.

    info: :func:`amfe.training.data.dataset_info` of the new data; pixelation:
    how its images were made (:func:`amfe.training.train.pixelation_of`);
    labels (n, 6): its training labels, positive where the normaliser takes logs.
    """
    check_grid(start, data_path, info, pixelation)
    bad = Normalizer.nonpositive_logs(labels, start["normalizer"].log.numpy())
    if bad:
        raise AmfeError(f"--init {start['record']['path']} standardises these labels as "
                        f"logarithms, but the data set {data_path} has non-positive values of "
                        f"them: {bad}")


def check_grid(start, data_path, info, pixelation):
    """AmfeError unless the new data set's images are made as the initial model's: the same
    layers, cells and sampling; another in-plane size only for a size-free network."""
    path, ckpt = start["record"]["path"], start["ckpt"]
    # A network that pools globally over its last map reads any H x W with the same
    # weights: it may start from a model of another bed size (issue 34: fine-tuned on each
    # size), as long as the layers, channels, cells and sampling are the same.
    other_size = start["arch"] in SIZE_FREE_ARCHS and \
        tuple(info["image_shape"])[:1] == tuple(ckpt["image_shape"])[:1]
    if not other_size:
        check_image_shape(ckpt, info["image_shape"], f"the data set {data_path}", path)
    theirs = ckpt.get("pixelation") or {}
    skip = ("scale", "bed_size") if other_size else ("scale",)
    for key in (k for k in pixelation if k not in skip):   # the grid, not the scale's name
        a, b = np.atleast_1d(theirs.get(key, np.nan)), np.atleast_1d(pixelation[key])
        if a.shape != b.shape or not np.allclose(a, b, rtol=1e-9, atol=0):
            raise AmfeError(f"--init {path} was trained on images with {key} {theirs.get(key)}, "
                            f"the data set {data_path} has {pixelation[key]}: fine-tune on a "
                            "data set of the same scale")


def widened_fill_range(old, new):
    """The fill range over both training sets: the old model's and the new data's."""
    if not old:
        return new
    return dict(new, lo=float(min(old["lo"], new["lo"])), hi=float(max(old["hi"], new["hi"])),
                definition=new["definition"] + "; widened to the initial model's range")
