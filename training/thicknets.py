"""Networks of one thickness each, read by the anybed stack beside the anybed network (issue 46).

The anybed network (amfe.training.anybed) reads 2-6 layers and every material
with one set of weights, fine-tuned from the 3-layer small model. On 2-layer
beds a network of their own, trained from scratch on those beds alone with its
outputs in log space, reads them better, nu_xy most (docs/surrogate.md, "Any
bed"). Its output is one more column of the stack at its thickness
(amfe.training.anystack), as the small model's is at 3 layers, so the stack
weighs the two networks on beds neither saw.

Its input is the bed's own image stack, then the descriptors nu and psi as
constant planes (:class:`amfe.training.multiscale.MultiScaleNet` with
``features`` 2, as anybed's, without the padding to six layers):
(2 L + 2, H, W) for a bed of L layers.

The checkpoints are ordinary surrogate checkpoints (arch ``multiscale``, run in
numpy by amfe.training.npnet) named in :data:`THICK_FILES`, with a ``thick``
block: the layers, the descriptors, the training data and its augmentation
(run/train/train_thick.py writes them). A network trained with the bed turned
upside down too (:data:`BOTH_WAYS_UP`, the 5-layer one) reads each bed both ways
up and averages the two.
"""
import numpy as np

from amfe.errors import AmfeError
from amfe.training.anybed import REFERENCE, SCALE

#: The thicknesses [layers] with a network of their own, and its checkpoint in amfe/models/.
THICK_FILES = {2: "thick_2layers.pt", 5: "thick_5layers.pt"}
#: The descriptors the head reads, after the image layers.
THICK_DESCRIPTORS = ("nu", "psi")
#: The training augmentation (the ``thick`` block's ``augment``) with every symmetry of a
#: square bed of whole layers, upside down included: such a network reads both ways up.
BOTH_WAYS_UP = "d4z"


def thick_inputs(fill, bonds, nu, psi):
    """(n, 2 L + 2, H, W) float32 inputs of n beds: fill, bonds (n, L, H, W); nu, psi (n,)."""
    fill, bonds = np.asarray(fill, np.float32), np.asarray(bonds, np.float32)
    n, _, H, W = fill.shape
    d = np.stack([(np.asarray(v, np.float64) - REFERENCE[k]) / SCALE[k]
                  for k, v in zip(THICK_DESCRIPTORS, (nu, psi))], axis=-1).astype(np.float32)
    planes = np.broadcast_to(d.reshape(n, len(THICK_DESCRIPTORS), 1, 1),
                             (n, len(THICK_DESCRIPTORS), H, W))
    return np.ascontiguousarray(np.concatenate([fill, bonds, planes], axis=1))


def upside_down(layers, channels):
    """The channel order (list) of the inputs (:func:`thick_inputs`, ``channels`` of them) of a
    bed of ``layers`` layers turned upside down: its fill and bond layers in reverse order,
    the descriptor planes as they are. The six constants of a bed of whole layers do not
    change when it is turned over (its stiffness is reflected, which leaves every normal
    component), so a network trained on both ways reads both and averages them."""
    down = list(range(int(layers)))[::-1]
    return down + [int(layers) + i for i in down] + list(range(2 * int(layers), int(channels)))


def check_thick(sur, layers):
    """AmfeError unless the Surrogate ``sur`` is the network of ``layers`` layers."""
    block = sur.ckpt.get("thick") or {}
    if int(block.get("layers", -1)) != int(layers):
        raise AmfeError(f"{THICK_FILES.get(int(layers), 'the model')} is not a network of "
                        f"{int(layers)} layers (it says {block.get('layers')}); reinstall amfe")


def thick_members(models, fill, bonds, nu, psi):
    """(members, n, 6) outputs at 210 GPa of the network of the beds' thickness, or None where
    that thickness has none. models: {"thick": {layers: Surrogate}, ...}."""
    layers = int(np.shape(fill)[1])
    sur = (models.get("thick") or {}).get(layers)
    if sur is None:
        return None
    x = thick_inputs(fill, bonds, nu, psi)
    out = sur.run_members(x)
    if (sur.ckpt.get("thick") or {}).get("augment") == BOTH_WAYS_UP:
        flipped = np.ascontiguousarray(x[:, upside_down(layers, x.shape[1])])
        out = (out + sur.run_members(flipped)) / 2
    return out


def load_thick(directory=None):
    """{layers: Surrogate} of the installed networks of :data:`THICK_FILES` (in ``directory``,
    default amfe/models/); AmfeError for one missing or of another thickness."""
    from amfe.training.predict import Surrogate  # noqa: PLC0415 (predict imports the routes)
    from amfe.training.shipped import models_dir  # noqa: PLC0415
    out = {}
    for layers, name in THICK_FILES.items():
        path = (models_dir() if directory is None else directory) / name
        if not path.exists():
            raise AmfeError(f"the {layers}-layer network {path} is not installed; reinstall amfe")
        out[layers] = Surrogate.load(path)
        check_thick(out[layers], layers)
    return out


def created_stamps(thick):
    """{"layers": created} of networks {layers: Surrogate}: what a stack records it read."""
    return {str(layers): sur.ckpt.get("created") for layers, sur in sorted(thick.items())}
