"""The full stiffness as a network output: C (6, 6) SPD by construction, and its symmetries.

A stiffness head outputs 21 numbers per bed: the lower triangle of a
Cholesky factor L (6, 6), row by row, its diagonal made positive by a
softplus. C = L L^T + EIG_FLOOR I in a normalised unit (the
checkpoint's ``stiffness_scale`` [Pa]: C [Pa] = scale * C_normalised), so
every prediction is symmetric positive definite whatever the weights (its
smallest eigenvalue is at least EIG_FLOOR, which floating point keeps even
when L is ill-conditioned; L L^T alone can round to a tiny negative one), and
the nine engineering constants (Ex, Ey, Ez, nu_yz, nu_xz, nu_xy, G_yz, G_xz,
G_xy) follow from it as from a solve (amfe.model.averages.compliance_and_constants).

Voigt order xx, yy, zz, yz, xz, xy (docs/model.md, section 5). The image
symmetries the training augments with and the test-time averaging uses act
on C as a tensor, C' = M C M^T with M (6, 6) orthogonal (:func:`voigt_map`):

- a mirror in x (x -> -x, the image's W axis) flips the sign of the Voigt
  components with one x index, xz and xy: M = diag(1, 1, 1, 1, -1, -1), which
  changes the sign of C15, C16, C25, C26, C35, C36, C45, C46 (1-based);
- a mirror in y: M = diag(1, 1, 1, -1, 1, -1);
- the x <-> y swap (the image's transpose) permutes xx <-> yy and yz <-> xz.

The six-constant models keep their own path (a mirror leaves the six
constants unchanged, amfe.training.ensemble.predict_raw); these maps are
for models that predict C.
"""
import numpy as np
import torch
from torch.nn import functional as F

from amfe.model.averages import compliance_and_constants
from amfe.training.data import flip_images
from amfe.training.device import device_of
from amfe.training.ensemble import symmetries, tta_mode

N_CHOLESKY = 21
NINE = ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy", "G_yz", "G_xz", "G_xy")
# C's smallest eigenvalue, normalised unit (C's entries are of order one there).
EIG_FLOOR = 1e-6
_ROWS, _COLS = np.tril_indices(6)


def cholesky_factor(raw):
    """L (n, 6, 6) lower triangular with a positive diagonal from raw (n, 21) outputs."""
    if raw.shape[-1] != N_CHOLESKY:
        raise ValueError(f"a stiffness head has {N_CHOLESKY} outputs, got {raw.shape[-1]}")
    L = raw.new_zeros(*raw.shape[:-1], 6, 6)
    L[..., _ROWS, _COLS] = raw
    diag = torch.diagonal(L, dim1=-2, dim2=-1)
    return L - torch.diag_embed(diag) + torch.diag_embed(F.softplus(diag))


def stiffness_from_raw(raw):
    """C = L L^T + EIG_FLOOR I (n, 6, 6), normalised unit, SPD by construction, from raw (n, 21)."""
    L = cholesky_factor(raw)
    return L @ L.transpose(-1, -2) + EIG_FLOOR * torch.eye(6, dtype=raw.dtype, device=raw.device)


def voigt_map(flip_x=False, flip_y=False, transpose=False):
    """M (6, 6) float64 with C' = M C M^T for the image mirrored in x, in y, then x <-> y swapped.

    The order is flip_images's (amfe.training.data): the mirrors first, then the
    transpose, so M = P @ S. M is orthogonal; the map back is M^T.
    """
    s = np.ones(6)
    if flip_x:
        s[[4, 5]] *= -1
    if flip_y:
        s[[3, 5]] *= -1
    M = np.diag(s)
    if transpose:
        M = np.eye(6)[[1, 0, 2, 4, 3, 5]] @ M
    return M


def transform_stiffness(C, flip_x=False, flip_y=False, transpose=False, inverse=False):
    """C (..., 6, 6) (numpy or torch) of the transformed image: M C M^T (inverse: M^T C M)."""
    M = voigt_map(flip_x, flip_y, transpose)
    if inverse:
        M = M.T
    if isinstance(C, torch.Tensor):
        M = torch.as_tensor(M, dtype=C.dtype, device=C.device)
        return M @ C @ M.T
    return M @ np.asarray(C) @ M.T


def augment_stiffness(images, C, generator=None, square=True):
    """Random mirrors (and x <-> y swaps on square images) of a batch, with C transformed alike.

    images (n, layers, H, W), C (n, 6, 6) torch; returns both transformed.
    """
    n = images.shape[0]
    draws = torch.randint(0, 2, (n, 3), generator=generator).bool()
    if not square:
        draws[:, 2] = False
    xs, cs = [], []
    for k in range(n):
        fx, fy, tr = (bool(v) for v in draws[k])
        xs.append(flip_images(images[k:k + 1], fx, fy, tr))
        cs.append(transform_stiffness(C[k:k + 1], fx, fy, tr))
    return torch.cat(xs), torch.cat(cs)


def nine_from_stiffness(C):
    """The nine constants (..., 9) of C (..., 6, 6) as a torch tensor, NINE order;
    differentiable (the stiffness head's loss) and batched (its predictions).

    Ex = 1/S11, Ey = 1/S22, Ez = 1/S33, nu_yz = -S32/S22, nu_xz = -S31/S11,
    nu_xy = -S21/S11, G_yz = 1/S44, G_xz = 1/S55, G_xy = 1/S66 with S = C^-1:
    amfe.model.averages.compliance_and_constants's formulas, without its checks.
    """
    S = torch.linalg.inv(C)
    d = torch.diagonal(S, dim1=-2, dim2=-1)
    return torch.stack([1 / d[..., 0], 1 / d[..., 1], 1 / d[..., 2], -S[..., 2, 1] / d[..., 1],
                        -S[..., 2, 0] / d[..., 0], -S[..., 1, 0] / d[..., 0],
                        1 / d[..., 3], 1 / d[..., 4], 1 / d[..., 5]], dim=-1)


def constants_from_stiffness(C):
    """The nine constants (n, 9) float64 [Pa, -] of stiffnesses C (n, 6, 6) [Pa], in NINE order.

    Exactly amfe.model.averages.compliance_and_constants per bed (which checks
    C is finite and positive definite).
    """
    C = np.asarray(C, np.float64).reshape(-1, 6, 6)
    out = np.empty((C.shape[0], 9))
    for k, c in enumerate(C):
        props = compliance_and_constants(c)[1]
        out[k] = [props[name] for name in NINE]
    return out


def predict_stiffness(net, images, extra=None, tta="none", scale=1.0):
    """C (n, 6, 6) float64 [Pa] of a stiffness network, averaged over the TTA symmetries as a
    tensor.

    ``net(images)`` (or ``net(images, extra)``, ``extra`` (n, ...) per image) returns raw
    (n, 21) outputs; the symmetric images go through the network as one batch on its
    device, and each image's C is mapped back (M^T C' M) before the average, so the
    result of a mirrored image is exactly the mirrored result (to rounding).
    """
    net.eval()
    syms = symmetries(tta_mode(tta), images.shape[-1] == images.shape[-2])
    dev = device_of(net)
    views = torch.cat([flip_images(images, *sym) for sym in syms]).to(dev)
    with torch.inference_mode():
        if extra is None:
            raw = net(views)
        else:
            raw = net(views, extra.repeat(len(syms), *([1] * (extra.dim() - 1))).to(dev))
    C = stiffness_from_raw(raw.cpu().double()).view(len(syms), images.shape[0], 6, 6)
    acc = 0.0
    for k, sym in enumerate(syms):
        acc = acc + transform_stiffness(C[k], *sym, inverse=True)
    return (acc / len(syms)).numpy() * float(scale)
