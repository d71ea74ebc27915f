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
  (amfe.training.predict.summarize_members), as for a six-constant ensemble.

:func:`summarize` is what ``Surrogate.predict`` calls: a six-constant
checkpoint goes through exactly the path it always took.
"""
import numpy as np
import torch

HEAD = "stiffness"


def is_stiffness(ckpt):
    """True for a checkpoint whose members output the full stiffness (21 Cholesky entries)."""
    return ckpt.get("head") == HEAD


def nine_constants(C):
    """The nine constants (..., 9) float64 [Pa, -] of C (..., 6, 6) [Pa], in NINE order.

    Ex = 1/S11, Ey = 1/S22, Ez = 1/S33, nu_yz = -S32/S22, nu_xz = -S31/S11,
    nu_xy = -S21/S11, G_yz = 1/S44, G_xz = 1/S55, G_xy = 1/S66 with S = C^-1;
    NaN for a C that is not finite.
    """
    C = np.asarray(C, np.float64)
    out = np.full(C.shape[:-2] + (9,), np.nan)
    ok = np.isfinite(C).all(axis=(-1, -2))
    S = np.linalg.inv(C[ok])
    d = np.diagonal(S, axis1=-2, axis2=-1)
    out[ok] = np.stack([1 / d[:, 0], 1 / d[:, 1], 1 / d[:, 2], -S[:, 2, 1] / d[:, 1],
                        -S[:, 2, 0] / d[:, 0], -S[:, 1, 0] / d[:, 0],
                        1 / d[:, 3], 1 / d[:, 4], 1 / d[:, 5]], axis=-1)
    return out


def member_stiffness(sur, x, batch_size=None):
    """C of every member (members, n, 6, 6) float64 [Pa], each averaged over the TTA images.

    x: the validated image tensor (n, channels, H, W) float32.
    """
    from amfe.training.data import flip_images
    from amfe.training.device import device_of
    from amfe.training.predict import CPU_PASS_IMAGES, GPU_PASS_IMAGES, symmetries
    from amfe.training.stiffness import stiffness_from_raw, transform_stiffness
    syms = symmetries(sur.tta, x.shape[-1] == x.shape[-2])
    scale = float(sur.ckpt["stiffness_scale"])
    out = np.empty((sur.n_members, x.shape[0], 6, 6))
    for m, net in enumerate(sur.nets):
        net.eval()
        dev = device_of(net)
        size = batch_size or (CPU_PASS_IMAGES if dev.type == "cpu" else GPU_PASS_IMAGES)
        chunk = max(1, int(size) // len(syms))
        with torch.inference_mode():
            for s in range(0, x.shape[0], chunk):
                xb = x[s:s + chunk]
                views = torch.cat([flip_images(xb, *sym) for sym in syms])
                raw = net(views.to(dev)).cpu().double()
                C = stiffness_from_raw(raw).view(len(syms), xb.shape[0], 6, 6)
                acc = 0.0
                for k, sym in enumerate(syms):
                    acc = acc + transform_stiffness(C[k], *sym, inverse=True)
                out[m, s:s + xb.shape[0]] = (acc / len(syms)).numpy() * scale
    return out


def member_constants(sur, x, batch_size=None):
    """The six constants of every member's C, (members, n, 6) (the spread's input)."""
    return nine_constants(member_stiffness(sur, x, batch_size))[..., :6]


def summarize(sur, images, batch_size=None):
    """Surrogate.predict's ensemble part: {mean, spread, score, nonfinite, flagged}, and for a
    stiffness head also stiffness (n, 6, 6) [Pa], constants9 (n, 9) (NINE order) and spread9
    (n, 9), the members' relative spread of the nine."""
    from amfe.training.data import image_batch
    from amfe.training.predict import summarize_members
    if not is_stiffness(sur.ckpt):
        return summarize_members(sur.member_outputs(images, batch_size), sur.spread_scale,
                                 sur.threshold)
    Cm = member_stiffness(sur, image_batch(images, sur.ckpt, sur.path), batch_size)
    per_member = nine_constants(Cm)
    res = summarize_members(per_member[..., :6], sur.spread_scale, sur.threshold)
    # The members' relative spread of all nine (the intervals' scale), as summarize_members's.
    res["spread9"] = ((per_member - per_member[:1]).std(axis=0)
                      / np.maximum(np.abs(per_member.mean(axis=0)), np.finfo(float).tiny))
    C = Cm.mean(axis=0)
    nine = nine_constants(C)
    bad = ~np.isfinite(nine).all(axis=1)
    res.update(mean=nine[:, :6], stiffness=C, constants9=nine, nonfinite=res["nonfinite"] | bad,
               flagged=res["flagged"] | bad)
    return res
