"""What a surrogate reads: the image kinds and the checked input array (no torch).

A network's input stacks one or more image kinds along the channel axis
(:data:`INPUT_KINDS`): "fill", the volume-fraction image (the paper's), and
"bonds", the bond-stiffness image (:mod:`amfe.dataset.bondimage`); inputs ("fill",
"bonds") give (2 layers, H, W) channels, the fill layers first.
"""
import numpy as np

from amfe.errors import AmfeError
from amfe.training.checkpoint import check_image_shape

INPUT_KINDS = {"fill": "images", "bonds": "bond_images"}   # kind: data-set array
DEFAULT_INPUTS = ("fill",)


def check_inputs(inputs):
    """``inputs`` as a tuple of known image kinds, without repeats (AmfeError otherwise)."""
    if isinstance(inputs, str):
        inputs = tuple(k.strip() for k in inputs.split(",") if k.strip())
    inputs = tuple(str(k) for k in inputs)
    bad = [k for k in inputs if k not in INPUT_KINDS]
    if bad or not inputs or len(set(inputs)) != len(inputs):
        raise AmfeError(f"inputs must be distinct image kinds from {', '.join(INPUT_KINDS)}, "
                        f"got {','.join(inputs) or 'none'}")
    return inputs


def image_array(images, ckpt, path="the model"):
    """``images`` (n, channels, H, W) or one (channels, H, W) as a float32 array (n, channels,
    H, W); AmfeError unless it is an array of numbers of the checkpoint's image shape."""
    try:
        x = np.asarray(images, np.float32)
    except (TypeError, ValueError) as exc:
        raise AmfeError(f"images must be an array of numbers (n, layers, H, W), got "
                        f"{type(images).__name__} ({exc})") from None
    if x.ndim == 3:
        x = x[None]
    if x.ndim != 4:
        raise AmfeError(f"images must be (n, layers, H, W), got shape {tuple(x.shape)}")
    check_image_shape(ckpt, x.shape[1:], "the image", path)
    return x
