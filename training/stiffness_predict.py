"""Inference of a stiffness-head checkpoint through :class:`amfe.training.predict.Surrogate`.

A checkpoint with ``head`` "stiffness" (amfe.training.stiffness_train) holds
members whose 21 outputs are the Cholesky factor of C in the unit
``stiffness_scale`` [Pa]. Its prediction of a bed:

- each member's C (6, 6) [Pa] is averaged over the bed's symmetric images
  (the checkpoint's ``tta``), every image's C mapped back to the bed's
  axes as a tensor (M^T C' M, amfe.training.stiffness.transform_stiffness),
  so the prediction of a mirrored bed is the mirrored prediction;
- C is the members' mean (a mean of SPD matrices is SPD);
- the six constants (``mean``) and the three shear moduli are those of that C
  (:func:`nine_constants`, the formulas of
  amfe.model.averages.compliance_and_constants, batched);
- the spread and flag are those of the members' own six constants
  (amfe.training.ensemble.summarize_members), as for a six-constant ensemble.

:func:`summarize` is what ``Surrogate.predict`` calls: a six-constant
checkpoint goes through exactly the path it always took.
"""
import numpy as np

from amfe.training import STIFFNESS_HEAD
from amfe.training.ensemble import (
    CPU_PASS_IMAGES,
    GPU_PASS_IMAGES,
    relative_spread,
    summarize_members,
    symmetries,
)

# torch is imported by the functions that run a stiffness head, not here: the six-constant
# models' numpy inference (amfe.training.npnet) imports this module and none of torch.


def is_stiffness(ckpt):
    """True for a checkpoint whose members output the full stiffness (21 Cholesky entries)."""
    return ckpt.get("head") == STIFFNESS_HEAD


def nine_constants(C):
    """The nine constants (..., 9) float64 [Pa, -] of C (..., 6, 6) [Pa], in NINE order
    (amfe.training.stiffness.nine_from_stiffness); NaN for a C that is not finite."""
    import torch

    from amfe.training.stiffness import nine_from_stiffness
    C = np.asarray(C, np.float64)
    out = np.full(C.shape[:-2] + (9,), np.nan)
    ok = np.isfinite(C).all(axis=(-1, -2))
    out[ok] = nine_from_stiffness(torch.from_numpy(C[ok])).numpy()
    return out


def member_stiffness(sur, x, batch_size=None):
    """C of every member (members, n, 6, 6) float64 [Pa], each averaged over the TTA images
    (amfe.training.stiffness.predict_stiffness), in passes of about ``batch_size`` images.

    x: the validated image tensor (n, channels, H, W) float32.
    """
    from amfe.training.device import device_of
    from amfe.training.stiffness import predict_stiffness
    n_syms = len(symmetries(sur.tta, x.shape[-1] == x.shape[-2]))
    scale = float(sur.ckpt["stiffness_scale"])
    out = np.empty((sur.n_members, x.shape[0], 6, 6))
    for m, net in enumerate(sur.nets):
        size = batch_size or (CPU_PASS_IMAGES if device_of(net).type == "cpu" else GPU_PASS_IMAGES)
        chunk = max(1, int(size) // n_syms)
        for s in range(0, x.shape[0], chunk):
            out[m, s:s + chunk] = predict_stiffness(net, x[s:s + chunk], tta=sur.tta, scale=scale)
    return out


def member_constants(sur, x, batch_size=None):
    """The six constants of every member's C, (members, n, 6) (the spread's input)."""
    return nine_constants(member_stiffness(sur, x, batch_size))[..., :6]


def summarize(sur, images, batch_size=None):
    """Surrogate.predict's ensemble part: {mean, spread, score, nonfinite, flagged}, and for a
    stiffness head also stiffness (n, 6, 6) [Pa], constants9 (n, 9) (NINE order) and spread9
    (n, 9), the members' relative spread of the nine."""
    if not is_stiffness(sur.ckpt):
        return summarize_members(sur.member_outputs(images, batch_size), sur.spread_scale,
                                 sur.threshold)
    from amfe.training.data import image_batch
    Cm = member_stiffness(sur, image_batch(images, sur.ckpt, sur.path), batch_size)
    per_member = nine_constants(Cm)
    res = summarize_members(per_member[..., :6], sur.spread_scale, sur.threshold)
    res["spread9"] = relative_spread(per_member)   # of all nine: the intervals' scale
    C = Cm.mean(axis=0)
    nine = nine_constants(C)
    bad = ~np.isfinite(nine).all(axis=1)
    res.update(mean=nine[:, :6], stiffness=C, constants9=nine, nonfinite=res["nonfinite"] | bad,
               flagged=res["flagged"] | bad)
    return res
