"""Static uniform boundary conditions (SUBC) beside KUBC (docs/model.md, section 9).

Pure, vectorised numpy. Units follow the caller (amfe feeds the
non-dimensional frame: lengths / mean radius, forces / (E r^2)).

The boundary layer
------------------
B is KUBC's boundary set (:func:`amfe.model.kubc.boundary_particles`: centres
within one maximum radius of a face of the axis-aligned box of the centres),
x_p the centres relative to that box's centre x_c, V the bed's box (KUBC's V,
docs/model.md, section 5). Each p in B carries a weight a_p [length^2], a
share of the outward area of the box.

Weights. First the face shares

    a_p^0 = sum over the faces F that p belongs to of  n_F A_F / N_F,

n_F the outward unit normal of face F, A_F its area (of the box of the
centres), N_F the number of particles of B on F (a corner particle takes a
share of each of its faces). Then the smallest correction (least squares on
the stacked a_p) that makes the 12 conditions

    sum_p a_p = 0                     (3: the loads carry no net force)
    sum_p a_p (x) x_p = V I           (9: no net moment, and the weights
                                       measure the volume V)

exact. With X_p = (1, x_p), M (B,4) the stacked X_p, A (B,3) the stacked a_p
and G (4,3) = [0; V I] the conditions read M^T A = G. Minimising
1/2 ||A - A^0||_F^2 subject to them, with multipliers Lam (4,3), gives
A - A^0 = M Lam and M^T M Lam = G - M^T A^0: one 4x4 solve. M^T M is
singular exactly when the centres of B lie in one plane (or on a line):
then no weights satisfy the conditions and SUBC is refused.

Loads, strain, compliance
-------------------------
A macro-stress Sigma (3,3) puts the force f_p = Sigma a_p on p's
translations (no couples). Then sum_p f_p = 0 and sum_p f_p (x) x_p =
Sigma V, symmetric: the loads are self-equilibrated and their average
(Love-Weber) stress (1/V) sum_p f_p (x) x_p is Sigma exactly. The strain is
measured with the same weights,

    eps(u) = (1/V) sym( sum_p u_p (x) a_p ),

which rigid motions do not change (sum a_p = 0 removes translations; u = W x
with W antisymmetric gives (1/V) sym(W V I) = 0), and which is work
conjugate to the loads: sum_p f_p . u_p = V Sigma : eps(u). In Voigt form
(stress components, engineering shears) f = P sigma with P (6n,6) and
P^T u = V e(u). Hence, with K^+ any solution operator of K u = f,

    S_subc = (1/V) P^T K^+ P,   S_IJ = (1/V) F_I . U_J,   C_subc = (sym S)^-1:

one solve per unit stress, one dot product per entry (:func:`subc_average`).

Ordering (the minimal kinematic argument). For every Voigt strain e,

    1/2 V e : C_subc : e = min { 1/2 u^T K u : (1/V) P^T u = e }

(Lagrange: K u = P lam, P^T K^+ P lam = V e, so lam = C_subc e and the
minimum is 1/2 V e . C_subc e). KUBC's solution for e has u_p = eps x_p on
every p in B, so (1/V) P^T u = eps (1/V) sum_p x_p (x) a_p = eps: it is
admissible, and its energy is 1/2 V e : C_kubc : e when C_kubc comes from
the applied strain. So e : C_subc : e <= e : C_kubc : e for every e. amfe's
KUBC C uses the Bagi hull strain, which is the applied one when every hull
vertex is in B (fully scanned beds); where a hull vertex is not prescribed
(a track ending short of a face) the ordering is not guaranteed, and
:func:`energy_gap` measures it.

Not a bracket of the periodic value: with V the bed's box a finite cluster
lacks the bonds that cross the box's faces on the torus; on a simple cubic
lattice of n^3 particles in its box (n s)^3 both KUBC and SUBC give
Ex = (k_n / s)(n-1)/n exactly (the chains decouple), 1/n below the periodic
k_n / s.

Several pieces: each piece reaching all six faces gets its own weights,
balanced on it (:func:`subc_weights` with ``parts``) and its own pin; the
argument above holds piece by piece.

The free frame: a pin, not a null space
----------------------------------------
Nothing is prescribed, so K keeps its six rigid-body modes. amfe holds all
six DOFs of ONE particle (:func:`pinned_particle`). This is exact: the loads
are orthogonal to every rigid mode (no net force, no net moment, no
couples), so K u = f is consistent; its solutions differ by rigid motions,
the pin picks one, and eps(u) does not see rigid motions. A connected frame
with one particle held has no zero-energy mode left, so the reduced operator
is positive definite and KUBC's machinery applies unchanged
(MatZeroRowsColumns, CG + GAMG with the rigid modes as NEAR null space, a
non-singular coarse solve). A singular operator with the six modes as its
null space would need a singular coarse solve (SVD) in GAMG and projected
right-hand sides, and buys nothing here.
"""
import numpy as np

from amfe.errors import AmfeError
from amfe.model.averages import box_center, dual_corrected, symmetric, unit_strains
from amfe.model.kubc import boundary_particles
from amfe.model.loadcase import Group
from amfe.vocab import CASE_NAMES, VOIGT_PAIRS

#: Relative singular value below which the boundary set counts as flat.
DEGENERATE_TOL = 1e-8


def unit_stresses():
    """The six unit macro-stresses (6, 3, 3), Voigt order xx, yy, zz, yz, xz, xy.

    Case k has Voigt STRESS = unit vector k: case 3 has Sigma_yz = Sigma_zy = 1
    (the unit engineering strain has eps_yz = 1/2).
    """
    out = np.zeros((6, 3, 3))
    for k, (i, j) in enumerate(VOIGT_PAIRS):
        out[k, i, j] = out[k, j, i] = 1.0
    return out


def check_boundary_spans_volume(points, tol=DEGENERATE_TOL):
    """Raise AmfeError if ``points`` (B,3) lie on a line or in a plane.

    Flat when the smallest singular value of the centred points is below
    ``tol`` times the largest (a line when the middle one is too). Returns the
    relative singular values (3,).
    """
    p = np.asarray(points, dtype=float)
    if p.shape[0] < 4:
        raise AmfeError(f"SUBC needs at least 4 boundary particles not in one plane, "
                        f"got {p.shape[0]}")
    s = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    rel = s / s[0] if s[0] > 0 else np.zeros(3)
    if rel[1] > tol and rel[2] > tol:
        return rel
    what = "on a line" if rel[1] <= tol else "in a plane"
    raise AmfeError(
        f"SUBC refused: the {p.shape[0]} boundary particles lie {what} (relative singular "
        f"values of their centres {np.array2string(rel, precision=3)}), so no boundary loads "
        "are self-equilibrated and measure a volume; use --bc kubc, or a bed that spans a volume")


def subc_weights(centers, radii, volume, parts=None):
    """SUBC weights on KUBC's boundary set; see the module docstring.

    centers (n,3) [L], radii (n,) [L], volume V [L^3] (the bed's box);
    parts (n,) int: the load-carrying piece of each particle (None: one piece).
    Each piece's weights are corrected on their own, so that its loads balance
    (sum a = 0, sum a (x) (x - x_c) = V_c I with V_c its face shares' own
    measure trace(sum a0 (x) (x - x_c)) / 3); then all are scaled so that the
    V_c add up to V.
    Returns (index (B,) int: the particles of B; a (B,3) [L^2]: the weights,
    sum a = 0 and sum a (x) (x - x_c) = V I to round-off, per piece too;
    correction: ||a - a0'||_F / ||a0'||_F, how far the face shares (scaled as a)
    had to move). Raises AmfeError when a piece's part of B lies in a plane or on a line.
    """
    x = np.asarray(centers, dtype=float)
    index = np.flatnonzero(boundary_particles(x, radii))
    xb = x[index] - box_center(x)
    check_boundary_spans_volume(xb)
    rmax = float(np.max(radii))
    lo, hi = x.min(axis=0), x.max(axis=0)
    on_lo, on_hi = (x[index] - lo) <= rmax, (hi - x[index]) <= rmax   # (B,3): on -x.., +x..
    ext = hi - lo
    areas = np.array([ext[1] * ext[2], ext[0] * ext[2], ext[0] * ext[1]])
    # every face holds the particles that reach it, so no count is zero
    a0 = areas * (on_hi / on_hi.sum(axis=0) - on_lo / on_lo.sum(axis=0))
    piece = np.zeros(index.size, np.int64) if parts is None else np.asarray(parts)[index]
    a, natural = np.empty_like(a0), 0.0
    for c in np.unique(piece):
        sel = piece == c
        if parts is not None:
            check_boundary_spans_volume(xb[sel])
        M = np.concatenate([np.ones((int(sel.sum()), 1)), xb[sel]], axis=1)
        Vc = float(np.trace(xb[sel].T @ a0[sel])) / 3.0
        G = np.zeros((4, 3))
        G[1:] = Vc * np.eye(3)
        a[sel] = a0[sel] + M @ np.linalg.solve(M.T @ M, G - M.T @ a0[sel])
        natural += Vc
    scale = float(volume) / natural
    a *= scale
    return index, a, float(np.linalg.norm(a - scale * a0) / np.linalg.norm(scale * a0))


def subc_strain(u, index, a, volume):
    """Engineering Voigt strains (c, 6) of displacements u (c, n, 6 or 3).

    eps = (1/V) sym(sum_p u_p (x) a_p) over B, as
    (eps_xx, eps_yy, eps_zz, 2 eps_yz, 2 eps_xz, 2 eps_xy). Rigid motions give 0.
    """
    H = np.einsum("cbi,bj->cij", np.asarray(u, dtype=float)[:, index, :3], a) / float(volume)
    H = H + np.transpose(H, (0, 2, 1))               # 2 eps
    i, j = np.array(VOIGT_PAIRS).T
    return H[:, i, j] * np.where(i == j, 0.5, 1.0)


def pinned_particle(centers, boundary, parts=None):
    """The particles whose six DOFs are held, one per piece: outside B, nearest the box centre.

    A particle off the boundary keeps the pin away from the loads. Falls back
    to the piece's particle nearest the box centre when all of it is in B.
    parts (n,) int: the pieces (None: one). Returns an int array (k,).
    """
    x = np.asarray(centers, dtype=float)
    d2 = np.sum((x - box_center(x)) ** 2, axis=1)
    piece = np.zeros(len(x), np.int64) if parts is None else np.asarray(parts)
    inside = ~np.asarray(boundary, bool)
    pins = []
    for c in np.unique(piece):
        own = piece == c
        pool = np.flatnonzero(own & inside)
        pool = pool if pool.size else np.flatnonzero(own)
        pins.append(int(pool[np.argmin(d2[pool])]))
    return np.array(pins, np.int64)


def subc_groups(frame):
    """One :class:`~amfe.model.loadcase.Group` of the six unit-stress cases of ``frame``.

    The pinned particles' six DOFs (one per piece) are fixed at zero; ``forces``
    holds the loads f_p = Sigma_k a_p of the six unit stresses (translations only).
    """
    x = frame.centers
    n = x.shape[0]
    index, a, _ = subc_weights(x, frame.radii, frame.volume, frame.parts)
    fixed = np.zeros((n, 6), bool)
    fixed[pinned_particle(x, boundary_particles(x, frame.radii), frame.parts)] = True
    forces = np.zeros((6, n, 6))
    forces[:, index, :3] = np.einsum("cij,bj->cbi", unit_stresses(), a)
    zero = [np.zeros((n, 6)) for _ in range(6)]
    return [Group(fixed=fixed, values=zero, names=list(CASE_NAMES), forces=list(forces),
                  smoothed_aggregation=True)]


def subc_average(frame, groups, u, moments=None, diagnose=False, cross=None):
    """C (6,6), V and the record of SUBC's solutions ``u`` (6, n, 6), frame units.

    S_IJ = (1/V) F_I . U_J (work conjugacy; equal to the weights' strain of
    case J, :func:`subc_strain`), C = (sym S)^-1. cross: [D] with D_IJ =
    U_I . r_J (the solutions against the true residuals) or [None]: with it,
    S_IJ = (1/V) (F_I . U_J + D_IJ), second order in the solver's error
    (docs/model.md, section 9). Returns (C, V, stats) with stats =
    {"S_asymmetry": ||S - S^T|| / ||S||} (and "correction": ||D|| / ||F^T U||).
    ``moments`` and ``diagnose`` are unused (the stress is the applied one exactly).
    """
    V = frame.volume
    F = np.asarray(groups[0].forces)
    work, stats = dual_corrected(np.einsum("ink,jnk->ij", F, np.asarray(u)), cross, +1)
    S = work / V
    asym = float(np.linalg.norm(S - S.T) / np.linalg.norm(S))
    return np.linalg.inv(symmetric(S)), V, {"S_asymmetry": asym, **stats}


def kubc_admissible_strain(frame):
    """SUBC strains (6,6) of KUBC's six affine fields: the identity (the ordering's premise)."""
    x = frame.centers
    index, a, _ = subc_weights(x, frame.radii, frame.volume, frame.parts)
    u = np.einsum("kij,nj->kni", unit_strains(), x - box_center(x))
    return subc_strain(u, index, a, frame.volume)


def energy_gap(C_upper, C_lower, strains=None, seed=0, n_random=200):
    """min over strains e of (e C_upper e - e C_lower e) / (e C_upper e).

    strains (k,6) engineering Voigt; default the six unit strains and
    ``n_random`` normal random ones (seeded). Non-negative when C_lower is
    below C_upper in energy; its size is the smallest relative energy gap.
    """
    if strains is None:
        strains = np.vstack([np.eye(6), np.random.default_rng(seed).normal(size=(n_random, 6))])
    hi = np.einsum("ki,ij,kj->k", strains, C_upper, strains)
    lo = np.einsum("ki,ij,kj->k", strains, C_lower, strains)
    return float(np.min((hi - lo) / hi))
