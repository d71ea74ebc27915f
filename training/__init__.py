"""The CNN surrogate (paper sections 6-8, docs/model.md section 8): data, networks, training, use.

- :mod:`amfe.training.data`: a lazy torch Dataset over an amfe data set, seeded
  splits, label normalisation, label-preserving symmetries.
- :mod:`amfe.training.nets`: Custom Net, LeNet-5, AlexNet and VGG with a six-output
  linear regression head.
- :mod:`amfe.training.multiscale`: a multi-scale encoder that reads the holes.
- :mod:`amfe.training.train`: training one network or a seeded ensemble.
- :mod:`amfe.training.checkpoint`: plain-data checkpoints, loaded weights-only.
- :mod:`amfe.training.predict`: inference on images and beds, the ensemble flag.
- :mod:`amfe.training.npnet`, :mod:`amfe.training.torchfile`: the multi-scale network's
  inference in numpy and a checkpoint read without torch (what ``amfe predict`` runs).
- :mod:`amfe.training.inputs`: the image kinds a network reads, the checked input array.
- :mod:`amfe.training.metrics`, :mod:`amfe.training.plots`: errors per property, curves.
- :mod:`amfe.training.stiffness`, :mod:`amfe.training.stiffness_fit`: the full stiffness
  through a Cholesky head, its tensor symmetries, fitting and saving such models.
- :mod:`amfe.training.stiffness_train`, :mod:`amfe.training.stiffness_predict`: a stiffness
  head on a trained multi-scale model (``amfe train --head stiffness``) and its prediction
  through the same Surrogate / amfe predict path.
- :mod:`amfe.training.anysize`: a fully convolutional net for any bed size;
  :mod:`amfe.training.imagebox`: the whole-cell rule.
- :mod:`amfe.training.conformal`: split conformal intervals per bed size.

This module imports nothing heavy, so the amfe command line can build its
parsers without importing torch.
"""
from amfe.errors import AmfeError

ARCH_NAMES = ("custom", "lenet5", "alexnet", "vgg", "multiscale")
AUGMENTATIONS = ("none", "flips", "d4")
SCHEDULES = ("constant", "cosine")
LOSSES = ("mse", "l1")
#: A checkpoint's ``head`` when its members output the full stiffness (amfe.training.stiffness).
STIFFNESS_HEAD = "stiffness"
# Which keyword arguments each network takes, and their JSON-able types.
ARCH_ARGS = {"custom": {"padding": str, "width": float, "convs": int},
             "lenet5": {},
             "alexnet": {"width": float, "hidden": list, "dropout": float},
             "vgg": {"width": float, "hidden": list, "dropout": float, "batch_norm": bool},
             "multiscale": {"width": float, "hidden": list, "n_fill": int, "outputs": int,
                            "features": int, "channels": list}}


def check_arch_args(arch, arch_args):
    """``arch_args`` as a dict for network ``arch`` (hidden, channels as int tuples); AmfeError
    for an unknown network or argument."""
    if arch not in ARCH_ARGS:
        raise AmfeError(f"unknown architecture {arch!r}; choose one of {', '.join(ARCH_ARGS)}")
    arch_args = dict(arch_args or {})
    unknown = set(arch_args) - set(ARCH_ARGS[arch])
    if unknown:
        raise AmfeError(f"architecture {arch} takes no argument(s) {', '.join(sorted(unknown))} "
                        f"(it takes: {', '.join(ARCH_ARGS[arch]) or 'none'})")
    for key in ("hidden", "channels"):
        if key in arch_args:
            arch_args[key] = tuple(int(h) for h in arch_args[key])
    return arch_args
