"""Thick beds read through their 3-layer windows, and intervals per thickness (issue 46).

The anybed network (amfe.training.anybed) learned 4-6 layers from about 1 000
beds a thickness, against the 40 000 3-layer beds its start, the small model,
saw; on thick beds its errors are about twice those at 3 layers. A bed of L
layers also holds L - 2 windows of three consecutive layers, which the same
network reads at 3 layers (with the bed's nu and psi), where it is good. The
*stack* combines them, per thickness L and per constant k, linearly in log
space (docs/surrogate.md, "Any bed"):

    log y_k = c_0 + c_1 log d_k + c_2 mean_w log w_k + c_3 min_w log w_k
              + c_4 max_w log w_k + c_5 log w_k(bottom) + c_6 log w_k(top)
              + sum_j (a_j log d_j + b_j mean_w log w_j) + c_7 nu + c_8 psi
              + the layers' mean fill and bond images (and the emptiest layer's),

d the network's output on the whole bed, w its outputs on the windows. Beds of
2 and 3 layers have no windows to read; their stack is the same map without
the window terms, a correction of the network by what it underfits. The
coefficients are a ridge fit on beds the network never saw; each ensemble
member is stacked on its own outputs, so the members' spread stays the
ensemble's. The intervals are calibrated per thickness (2-6 layers), on the
stack's cross-fitted outputs (every bed predicted by a fit that did not see it).

A 3-layer bed is also read by the small model, trained on 40 000 steel beds:
its stack has two more columns, log s_k of the small model's output and log
r_k of the network's at steel's nu and psi, so that it can take the small
model's reading of the geometry and the network's of the material
(s_k d_k / r_k; :data:`STEEL_LAYERS`). A bed of 2 or 5 layers is also read by
the network of its own thickness (amfe.training.thicknets): one more column, log t_k.
These other networks' reads are the stack's *extra* reads (:data:`EXTRA_READS`).

Pure numpy: amfe.training.anypredict runs the network and calls these.
"""
import json
from typing import NamedTuple, Optional

import numpy as np

from amfe.errors import AmfeError
from amfe.training.thicknets import THICK_FILES

#: The stack's file in amfe/models/ (run/train/fit_anybed_stack.py writes it).
STACK_FILE = "anybed_stack.json"
FORMAT, FORMAT_VERSION = "amfe.anybed_stack", 2
#: The thinnest bed with windows to stack: a 3-layer bed is its own window.
MIN_STACKED = 4
#: The thicknesses whose stack also reads the small model and the network at steel (the
#: small model's own beds: 3 layers).
STEEL_LAYERS = (3,)
#: How many other networks' outputs the stack reads at each thickness: at 3 layers the small
#: model and the network at steel, at those with a network of their own that network.
EXTRA_READS = {**{layers: 1 for layers in THICK_FILES}, **{layers: 2 for layers in STEEL_LAYERS}}


class Reads(NamedTuple):
    """What the stack reads of n beds, for each of m ensemble members.

    direct (m, n, 6): the network's outputs on the whole beds; windows (m, w, n, 6): on
    their 3-layer windows, or None (2-3 layers); nu, psi (n,); means (n, q):
    :func:`image_means`; extra (q, m, n, 6) or None: other networks' member m on the beds,
    q = :data:`EXTRA_READS` of their thickness (3 layers: the small model and the network
    at steel's nu and psi; 2 and 5 layers: the network of that thickness).
    """
    direct: np.ndarray
    windows: Optional[np.ndarray]
    nu: np.ndarray
    psi: np.ndarray
    means: np.ndarray
    extra: Optional[np.ndarray] = None

    def rows(self, sel):
        """The same reads of the beds ``sel`` (bool or index array over the n beds)."""
        idx = np.asarray(sel)
        idx = np.flatnonzero(idx) if idx.dtype == bool else idx

        def cut(a, axis):
            return None if a is None else np.take(np.asarray(a, np.float64), idx, axis=axis)
        return Reads(cut(self.direct, 1), cut(self.windows, 2), cut(self.nu, 0),
                     cut(self.psi, 0), cut(self.means, 0), cut(self.extra, 2))

    def design(self, k, m):
        """:func:`design` of constant k for member m."""
        return design(k, self.direct[m], None if self.windows is None else self.windows[m],
                      self.nu, self.psi, self.means,
                      None if self.extra is None else self.extra[:, m])


def window_starts(layers):
    """The first layer of each 3-layer window of a bed of ``layers`` layers (bottom first)."""
    return list(range(int(layers) - 2)) if int(layers) >= MIN_STACKED else []


def image_means(fill, bonds):
    """(n, 2 L + 2): each layer's mean fill and bond image, and the emptiest layer's of each,
    of images fill, bonds (n, L, H, W): what the stack reads of the bed beside the network."""
    fm = np.asarray(fill, np.float64).mean(axis=(2, 3))
    bm = np.asarray(bonds, np.float64).mean(axis=(2, 3))
    return np.column_stack([fm, bm, fm.min(axis=1), bm.min(axis=1)])


def design(k, direct, windows, nu, psi, means, extra=None):
    """(n, p) design of constant k for one member's outputs.

    direct (n, 6) > 0 on the whole beds; windows (w, n, 6) > 0 on their 3-layer windows, or
    None for a bed of 2 or 3 layers; nu, psi (n,); means (n, q): :func:`image_means`;
    extra (q, n, 6) > 0 or None: the other networks' outputs (:class:`Reads`).
    Columns: 1, log d_k, and, with windows, mean, min, max, bottom and top of log w_k and
    mean log w of the five other constants; then log d of the five others, nu, psi and
    the image means; with extra reads, the log of each one's output k last.
    """
    ld = np.log(np.asarray(direct, np.float64))
    cols = [np.ones(ld.shape[0]), ld[:, k]]
    if windows is not None:
        lw = np.log(np.asarray(windows, np.float64))
        cols += [lw[..., k].mean(0), lw[..., k].min(0), lw[..., k].max(0), lw[0, :, k],
                 lw[-1, :, k], *np.delete(lw.mean(0), k, axis=1).T]
    cols += [*np.delete(ld, k, axis=1).T, np.asarray(nu, np.float64),
             np.asarray(psi, np.float64), *np.asarray(means, np.float64).T]
    if extra is not None:
        cols += list(np.log(np.asarray(extra, np.float64)[:, :, k]))
    return np.column_stack(cols)


def n_columns(layers):
    """The number of columns of :func:`design` for a bed of ``layers`` layers (its design of
    one made-up bed, so the count cannot drift from the design)."""
    starts = window_starts(layers)
    windows = np.ones((len(starts), 1, 6)) if starts else None
    means = image_means(np.ones((1, int(layers), 1, 1)), np.ones((1, int(layers), 1, 1)))
    q = EXTRA_READS.get(int(layers))
    extra = np.ones((q, 1, 6)) if q else None
    return design(0, np.ones((1, 6)), windows, [0.3], [0.08], means, extra).shape[1]


def _positive(reads):
    """(n,) bool: the beds whose outputs are all positive (the stack reads their logs)."""
    ok = np.all(np.asarray(reads.direct) > 0, axis=(0, 2))
    if reads.windows is not None:
        ok &= np.all(np.asarray(reads.windows) > 0, axis=(0, 1, 3))
    if reads.extra is not None:
        ok &= np.all(np.asarray(reads.extra) > 0, axis=(0, 1, 3))
    return ok


def stack(coefs, reads):
    """(m, n, 6) stacked members: coefs (6, p); reads: :class:`Reads` of the n beds.

    A bed with a non-positive output (no log) keeps its direct members: finite, unstacked.
    """
    direct = np.asarray(reads.direct, np.float64)
    coefs = np.asarray(coefs, np.float64)
    out = direct.copy()
    ok = _positive(reads)
    if not ok.any():
        return out
    sub = reads.rows(ok)
    for m in range(direct.shape[0]):
        for k in range(6):
            out[m, ok, k] = np.exp(sub.design(k, m) @ coefs[k])
    return out


def fit(reads, labels, ridge=1e-4):
    """coefs (6, p): the ridge fit of log labels (n, 6) on the members' mean design.

    reads: :class:`Reads` of beds the network never saw; ridge: the penalty per bed on
    every coefficient but the intercept (it keeps the near-collinear window columns from
    cancelling; 1e-4 chosen by 5-fold cross-validation on the fitting beds among 1e-2,
    1e-3 and 1e-4).
    """
    labels = np.asarray(labels, np.float64)
    if not (_positive(reads).all() and np.all(labels > 0)):
        raise AmfeError("the stack is fitted on beds with positive outputs and labels")
    coefs = []
    for k in range(6):
        X = np.mean([reads.design(k, m) for m in range(np.shape(reads.direct)[0])], axis=0)
        penalty = float(ridge) * labels.shape[0] * np.eye(X.shape[1])
        penalty[0, 0] = 0.0
        coefs.append(np.linalg.solve(X.T @ X + penalty, X.T @ np.log(labels[:, k])))
    return np.array(coefs)


def cross_fitted(reads, labels, folds=5, ridge=1e-4):
    """(m, n, 6) stacked members of every bed by a fit on the other folds (for calibration;
    the folds are a fixed shuffle of the beds, seed 0)."""
    n = labels.shape[0]
    fold = np.random.default_rng(0).permutation(n) % int(folds)
    out = np.empty(np.shape(reads.direct))
    for f in range(int(folds)):
        test, train = fold == f, fold != f
        c = fit(reads.rows(train), labels[train], ridge)
        out[:, test] = stack(c, reads.rows(test))
    return out


def load_stack(path, network_created):
    """The stack file's content, checked; None where there is no file.

    network_created: the anybed checkpoint's ``created`` stamp; a stack fitted to another
    network is refused (its coefficients read that network's outputs).
    """
    try:
        with open(path) as f:
            data = json.load(f)
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise AmfeError(f"{path}: not a readable anybed stack ({exc}); reinstall amfe") from None
    if data.get("format") != FORMAT or data.get("format_version") != FORMAT_VERSION:
        raise AmfeError(f"{path} is not an anybed stack of version {FORMAT_VERSION}")
    if data.get("network_created") != network_created:
        raise AmfeError(f"{path} was fitted to the anybed network of "
                        f"{data.get('network_created')}, not to the installed one of "
                        f"{network_created}: refit it (run/train/fit_anybed_stack.py)")
    # Checked and converted once here, so that a bed's prediction only looks its entry up.
    for layers, entry in data["layers"].items():
        coefs = np.asarray(entry["coefs"], np.float64)
        if coefs.shape != (6, n_columns(int(layers))):
            raise AmfeError(f"the anybed stack's coefficients for {int(layers)} layers are "
                            f"{coefs.shape}, not (6, {n_columns(int(layers))}): refit it "
                            "(run/train/fit_anybed_stack.py)")
        entry["coefs"] = coefs
    return data


def layer_entry(data, layers):
    """The stack's entry for ``layers`` ({coefs (6, p), calibration, ...}) of a stack read by
    :func:`load_stack`; None if there is none."""
    return None if data is None else data["layers"].get(str(int(layers)))

