"""The flag's error network: a bed's images -> the small model's likely error (issue 46).

The flag's logistic risk (amfe.training.flagrisk) reads summary features of a bed;
what they say of its error a quadratic logistic already reads (docs/surrogate.md,
"The flag"). This network reads the images themselves. It is the multi-scale net
(amfe.training.multiscale) started from a shipped member's weights, with 12
outputs: for each of the six constants the location ``mu`` and log scale ``log b``
of a Laplace distribution of the small model's signed relative error
``r = predicted / label - 1`` in units of :data:`SCALE`. It is trained
(run/train/train_flagnet.py) on beds that no network of the small model's chain
saw, on that Laplace likelihood plus the cross-entropy of the event "some
constant more than 10 % off" (:func:`bad_probability`, the constants taken as
independent). The logit of that probability is one more feature of the flag's
risk.

Inference is numpy (amfe.training.npnet), averaged over the four mirror images of
the bed (the error, like the six constants, does not change when a bed is
mirrored). The file is an ``.npz`` beside the flag file: the members' weights
(float16: a flag needs no more) and a JSON header.
"""
import json
import os

import numpy as np

from amfe.errors import AmfeError
from amfe.io.atomic import atomic_write
from amfe.training.ensemble import symmetries
from amfe.training.npnet import PASS_IMAGES, NumpyMultiScale, _flip

#: The format of the error network's file.
FLAGNET_FORMAT, FLAGNET_VERSION = "amfe.flagnet", 1
#: The unit of the relative error the network's outputs are in.
SCALE = 0.05
#: The views averaged: the four mirror images (flip x, flip y, no transpose), as the
#: small model's test-time averaging ("flips").
VIEWS = symmetries("flips")


def tail_probabilities(mu, logb, bad):
    """(n, 6) P(|r| > bad) of each constant under Laplace(mu, exp(logb)) (in :data:`SCALE`
    units; ``bad`` a plain relative error, e.g. 0.10). Stable for any mu, logb."""
    mu, b = np.asarray(mu, float), np.exp(np.clip(np.asarray(logb, float), -5.0, 5.0))
    t = bad / SCALE
    z_up, z_lo = (t - mu) / b, (mu + t) / b
    e_up, e_lo = 0.5 * np.exp(-np.abs(z_up)), 0.5 * np.exp(-np.abs(z_lo))
    up = np.where(z_up >= 0, e_up, 1 - e_up)     # P(r > t)
    lo = np.where(z_lo >= 0, e_lo, 1 - e_lo)     # P(r < -t)
    return np.clip(up + lo, 0.0, 1.0)


def bad_logit(mu, logb, bad):
    """(n,) the logit of P(some constant's |r| > bad), the constants independent; finite
    for every input (each constant's probability of staying inside clipped to [1e-6, 1])."""
    inside = np.clip(1.0 - tail_probabilities(mu, logb, bad), 1e-6, 1.0)
    log_good = np.minimum(np.log(inside).sum(axis=1), -1e-6)
    return np.log(-np.expm1(log_good)) - log_good


class FlagNet:
    """The error network's members (numpy) and header; :meth:`outputs`, :meth:`logit`."""

    def __init__(self, states, header):
        self.header = header
        self.image_shape = tuple(int(s) for s in header["image_shape"])
        self.members = [NumpyMultiScale(s, self.image_shape, header["arch_args"])
                        for s in states]

    def outputs(self, images, batch_size=PASS_IMAGES):
        """(mu, logb), each (n, 6), of images (n, layers, H, W): the members' mean over the
        four mirror images, each member's views of a chunk of beds in passes of about
        ``batch_size`` images (as amfe.training.npnet.predict_raw runs the model's)."""
        x = np.asarray(images, np.float32)
        if x.ndim != 4 or tuple(x.shape[1:]) != self.image_shape:
            raise AmfeError(f"the flag's error network reads images of shape "
                            f"{'x'.join(map(str, self.image_shape))}, got "
                            f"{'x'.join(map(str, x.shape[1:]))}")
        chunk = max(1, int(batch_size) // len(VIEWS))
        acc = np.zeros((len(x), 12))
        for s in range(0, len(x), chunk):
            xb = x[s:s + chunk]
            views = np.concatenate([_flip(xb, *view) for view in VIEWS])
            for net in self.members:
                acc[s:s + chunk] += net(views).reshape(len(VIEWS), len(xb), 12).sum(0)
        acc /= len(self.members) * len(VIEWS)
        return acc[:, :6], np.clip(acc[:, 6:], -5.0, 5.0)

    def logit(self, images, bad):
        """(n,) :func:`bad_logit` of images (n, layers, H, W)."""
        return bad_logit(*self.outputs(images), bad)


def save_flagnet(path, states, header):
    """Write the members' weights (name -> array dicts) and the header (JSON-able dict:
    image_shape, arch_args, what it was trained on) to ``path`` (.npz, atomically)."""
    arrays = {f"m{k}/{name}": np.asarray(v, np.float16)
              for k, state in enumerate(states) for name, v in state.items()}
    head = {"format": FLAGNET_FORMAT, "format_version": FLAGNET_VERSION,
            "members": len(states), **header}
    arrays["header"] = np.frombuffer(json.dumps(head).encode(), np.uint8)
    atomic_write(path, lambda fh: np.savez(fh, **arrays))


def load_flagnet(path):
    """The :class:`FlagNet` of a file; AmfeError for a missing or foreign one."""
    try:
        with np.load(path) as z:
            header = json.loads(bytes(z["header"]).decode())
            if header.get("format") != FLAGNET_FORMAT \
                    or header.get("format_version") != FLAGNET_VERSION:
                raise AmfeError(f"{path} is not an amfe flag error network of version "
                                f"{FLAGNET_VERSION}")
            states = [{name.split("/", 1)[1]: z[name].astype(np.float32) for name in z.files
                       if name.startswith(f"m{k}/")} for k in range(int(header["members"]))]
    except (OSError, ValueError, KeyError) as exc:
        raise AmfeError(f"cannot read the flag's error network {path}: {exc}") from None
    return FlagNet(states, header)


def flagnet_beside(flag_path, name):
    """The :class:`FlagNet` named ``name`` in the flag file's folder."""
    return load_flagnet(os.path.join(os.path.dirname(os.path.abspath(flag_path)), name))
