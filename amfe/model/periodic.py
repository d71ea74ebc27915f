"""Periodic boundary conditions on a periodic bed (docs/model.md, section 9), pure numpy.

The frame (:func:`amfe.model.frame.build_frame` with ``box``) lives on the
torus: bond b joins i and the image of j shifted by s_b (branch vector
l_b = x_j + s_b * L - x_i), the largest component wraps round the torus in
x, y and z, and V = Lx Ly Lz.

Unknowns and loads
------------------
Displacements are u_p = eps x_p + w_p with w periodic, rotations theta_p
periodic. The unknowns U = (u_p, theta_p) are the total ones on the torus
particles (x_p their wrapped positions); the affine part moves the image of j
by u_j + eps (s_b * L), so bond b sees the 12-vector

    q_b = (u_i, theta_i, u_j + d_b, theta_j),   d_b = eps (s_b * L):

an extra relative translation d_b on the bonds that cross a face and nothing
else (equivalently eps l_b + w_j - w_i: the two differ by the rigid
translation eps x_i, which K_b annihilates). The energy
W(U) = 1/2 sum_b q_b^T K_b q_b is least where

    K U = F(eps),   F = - sum_b Z_b^T K_b (0, 0, d_b, 0),

K the frame's stiffness assembled on the torus (the same element blocks at
indices i, j: today's assembly IS the torus matrix) and F from the crossing
bonds alone (:func:`periodic_rhs`). K's null space is the three uniform
translations (a rotation is not periodic); F is orthogonal to them (each
bond's element forces sum to zero), so particle 0's translations are pinned:
exact, since the solutions differ by a translation, which changes no q_b.

Stiffness
---------
C_IJ = (1/V) sum_b q_b(I)^T K_b q_b(J) for the six unit strains (Voigt,
engineering shear): the energy density's Hessian, the strain being the
applied one exactly. With q = Z U + j (j the jumps) and equilibrium
sum_b Z_b^T K_b q_b = 0 this is

    C_IJ = (1/V) (W0_IJ - F_I . U_J),   W0_IJ = sum over crossing bonds d_I . K_jj,uu d_J,

dot products only (:func:`periodic_average`): on a distributed solve F_I . U_J
is a VecDot and W0 a sum over the crossing bonds. The Love-Weber stress
sigma = (1/V) sum_b f_b (x) l_b (f_b the force bond b takes at j) gives the
same C (:func:`love_weber_stiffness`, the cross-check of ``--diagnose``):
dW/deps = sum_b f_b (x) l_b at equilibrium. Sigma is symmetric there: each
bond's moment balance gives l_b x f_b = -(m_i + m_j) and no couples are
applied.

Simple cubic lattice (spacing s, d_i = d_j = s/2): eps_xx stretches each
x-bond by eps s with w = 0, theta = 0, one x-bond per cell s^3, so
C11 = k_n / s for any n and C12 = 0. Shear gamma_xy: x-bonds slide by
(gamma/2) s - s theta_z, y-bonds by (gamma/2) s + s theta_z; theta_z = 0
minimises 1/2 k_t s^2 [(gamma/2 - theta)^2 + (gamma/2 + theta)^2], so
C66 = k_t / (2 s) (likewise C44, C55); torsion and bending springs do not
enter. No finite-n correction (tests).
"""
import numpy as np

from amfe.model.averages import dual_corrected, unit_strains, voigt
from amfe.model.element import element_blocks
from amfe.model.loadcase import Group
from amfe.vocab import CASE_NAMES


def crossing(frame):
    """Indices of the bonds that cross a face of the box (shift != 0)."""
    return np.flatnonzero(np.any(frame.shift != 0, axis=1))


def bond_jumps(frame, eps, bonds=slice(None)):
    """Jumps d_b = eps (s_b * L): (c, M, 3) for macro-strains eps (c,3,3), frame units."""
    sL = frame.shift[bonds] * frame.box
    return np.einsum("cij,bj->cbi", np.asarray(eps, dtype=float).reshape(-1, 3, 3), sL)


def _blocks(frame, bonds):
    b = frame.bonds
    return element_blocks(b.normal[bonds], b.d_i[bonds], b.d_j[bonds], frame.k_n[bonds],
                          frame.k_t[bonds], frame.kappa_n[bonds], frame.kappa_t[bonds])


def periodic_rhs(frame, eps=None):
    """Right-hand sides F (c, n, 6) of macro-strains eps (c,3,3) (default the six unit ones).

    For each crossing bond -K_ij[:, :3] d_b on particle i's six rows and
    -K_jj[:, :3] d_b on j's. Units: force (the frame's).
    """
    eps = unit_strains() if eps is None else np.asarray(eps, dtype=float).reshape(-1, 3, 3)
    cross = crossing(frame)
    _, Kij, Kjj = _blocks(frame, cross)
    d = bond_jumps(frame, eps, cross)
    n = frame.n_particles
    F = np.zeros((eps.shape[0], n, 6))
    for c in range(eps.shape[0]):
        np.add.at(F[c], frame.bonds.i[cross], -np.einsum("bkl,bl->bk", Kij[:, :, :3], d[c]))
        np.add.at(F[c], frame.bonds.j[cross], -np.einsum("bkl,bl->bk", Kjj[:, :, :3], d[c]))
    return F


SMOOTHED_FROM = 28_000
"""Particles from which a torus's block solve takes smoothed aggregation. Held at one
particle only, its unsmoothed-aggregation iterations grow with the bed (29, 34, 38 at
0.6, 0.9, 1.2 mm bases) and smoothed aggregation's do not (11-12), for 2.5x the
set-up: unsmoothed 1.28x KUBC's time at 0.6 mm (12 480 particles) against smoothed
1.39-1.49x; equal at 0.9 mm (28 704); 1.64x against 1.30x at 1.2 mm (50 880);
docs/benchmarks.md, "Both bounds within 1.5x"."""

SMOOTHED_RTOL_MAX = 1e-6
"""Tori take smoothed aggregation only at tighter rtol than this. At the second-order default
rtol 1e-5 (docs/model.md, section 9) unsmoothed aggregation needs 13-15, 14-19 and 15-21
iterations at 0.6, 1.2 and 1.8 mm bases and is cheaper at all three (one rank, CPU: 1.11
against 1.65 s, 5.5-6.3 against 8.0 s, 12.7 against 20.3 s; docs/benchmarks.md)."""


def periodic_groups(frame):
    """One :class:`~amfe.model.loadcase.Group` of the six unit-strain cases on the torus.

    The translations of each piece's first particle (particle 0 for one piece) are
    fixed at zero; ``forces`` are
    :func:`periodic_rhs`; CG starts from the affine fields eps (x - x_0),
    i.e. w = 0. Tori of :data:`SMOOTHED_FROM` particles and more take
    smoothed aggregation (``Group.smoothed_aggregation``) when solved tighter
    than :data:`SMOOTHED_RTOL_MAX`.
    """
    n = frame.n_particles
    fixed = np.zeros((n, 6), bool)
    parts = np.zeros(n, np.int64) if frame.parts is None else frame.parts
    fixed[np.unique(parts, return_index=True)[1], :3] = True   # one pin per piece (section 5)
    guesses = np.zeros((6, n, 6))
    guesses[:, :, :3] = np.einsum("kij,nj->kni", unit_strains(), frame.centers - frame.centers[0])
    return [Group(fixed=fixed, values=[np.zeros((n, 6)) for _ in range(6)],
                  names=list(CASE_NAMES), guesses=list(guesses),
                  forces=list(periodic_rhs(frame)),
                  smoothed_aggregation=n >= SMOOTHED_FROM,
                  smoothed_rtol_max=SMOOTHED_RTOL_MAX)]


def periodic_average(frame, groups, u, moments=None, diagnose=False, cross=None):
    """C (6,6), V = Lx Ly Lz and the record of the periodic solutions ``u`` (6, n, 6).

    C = (1/V) (W0 - F^T U) (module docstring), raw; cross: [D] with D_IJ =
    U_I . r_J (the solutions against the true residuals) or [None]: with it,
    C = (1/V) (W0 - F^T U - D), second order in the solver's error
    (docs/model.md, section 9). stats: C_asymmetry ("correction": ||D|| /
    ||W0 - F^T U||), and with ``diagnose`` love_weber_difference
    ||C - C_LW|| / ||C|| and love_weber_asymmetry (the largest relative
    stress asymmetry; of the uncorrected solutions).
    """
    V = float(np.prod(frame.box))
    crossing_bonds = crossing(frame)
    Kjj = _blocks(frame, crossing_bonds)[2]
    d = bond_jumps(frame, unit_strains(), crossing_bonds)
    W0 = np.einsum("ibk,bkl,jbl->ij", d, Kjj[:, :3, :3], d)
    F = np.asarray(groups[0].forces)
    energy, stats = dual_corrected(W0 - np.einsum("ink,jnk->ij", F, np.asarray(u)), cross, -1)
    C = energy / V
    stats["C_asymmetry"] = float(np.linalg.norm(C - C.T) / np.linalg.norm(C))
    if diagnose:
        C_lw, asym = love_weber_stiffness(frame, u)
        stats.update(love_weber_difference=float(np.linalg.norm(C - C_lw) / np.linalg.norm(C)),
                     love_weber_asymmetry=asym)
    return C, V, stats


def bond_dofs(frame, u, eps=None):
    """Bond DOF vectors q (c, M, 12) of solutions u (c, n, 6), plus the jumps of eps (c,3,3).

    Without ``eps`` (a non-periodic frame, or the fluctuation alone) no jump is added.
    """
    u = np.asarray(u, dtype=float)
    b = frame.bonds
    q = np.concatenate([u[:, b.i], u[:, b.j]], axis=2)
    if eps is not None and frame.shift is not None:
        q[:, :, 6:9] += bond_jumps(frame, eps)
    return q


def love_weber_stiffness(frame, u, eps=None, volume=None):
    """C (6,6) from the Love-Weber stresses of solutions u (6, n, 6), and their asymmetry.

    sigma = (1/V) sum_b f_b (x) l_b, f_b = (K_b q_b)[6:9] the force bond b
    takes at j, l_b its (shifted) branch vector; V = Lx Ly Lz unless given
    (for a non-periodic frame pass eps=None and its V: then sigma is the
    average stress of the applied loads). Column J = Voigt(sigma(u_J)).
    """
    if eps is None and frame.shift is not None:
        eps = unit_strains()
    V = float(np.prod(frame.box)) if volume is None else float(volume)
    q = bond_dofs(frame, u, eps)
    _, Kij, Kjj = _blocks(frame, slice(None))
    f = (np.einsum("blk,cbl->cbk", Kij, q[..., :6]) + np.einsum("bkl,cbl->cbk", Kjj, q[..., 6:]))
    l = frame.bonds.length[:, None] * frame.bonds.normal
    sig = np.einsum("cbi,bj->cij", f[..., :3], l) / V
    asym = max(float(np.linalg.norm(s - s.T) / np.linalg.norm(s)) for s in sig)
    return np.array([voigt(s) for s in sig]).T, asym
