"""Bagi volume averages, the 6x6 stiffness C, the compliance S and the constants.

docs/model.md, section 5. Pure, vectorised numpy; no MPI, no PETSc.

Units: the functions are unit-agnostic but must be fed a consistent system; at
amfe's interfaces that is SI (positions [m], displacements [m], forces [N],
volume [m^3], stress and stiffness [Pa], strain [-]).

Conventions:

- Voigt order (xx, yy, zz, yz, xz, xy). Stress vectors hold the tensor
  components; strain vectors hold engineering shears (gamma_yz = 2 eps_yz), so
  that sigma = C eps and the strain energy density is sigma . eps / 2.
- A displacement gradient H has H[i, j] = d u_i / d x_j.
- Matrix indices in the docstrings are 1-based as in docs/model.md (S11, S32);
  in code S11 is ``S[0, 0]`` and S32 is ``S[2, 1]``.
"""
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from amfe.errors import AmfeError
from amfe.signals import signals_deferred

#: Keys of the dict returned by :func:`compliance_and_constants`, in docs/model.md's order.
from amfe.vocab import CONSTANT_NAMES as CONSTANT_KEYS
from amfe.vocab import VOIGT_PAIRS as _VOIGT_PAIRS

# Voigt index pairs (xx, yy, zz, yz, xz, xy).
_VI = np.array([p[0] for p in _VOIGT_PAIRS])
_VJ = np.array([p[1] for p in _VOIGT_PAIRS])

_DEGENERATE_MSG = ("the kept particles span no volume (all centres in one plane "
                   "or on one line): cannot homogenize")


# --------------------------------------------------------------------------- #
# Convex hull of the particle centres
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class Hull:
    """Triangulated convex hull of the particle centres.

    Attributes
    ----------
    vertices : (K,) int
        Indices (into the centres array) of the hull vertices. Centres lying on
        a hull face or edge without being a corner of it (regular lattices have
        many) are not vertices; they do not enter the boundary integral.
    facets : (F, 3) int
        Vertex indices of each triangle, ordered counter-clockwise seen from
        outside, so that (x1 - x0) x (x2 - x0) points outward.
    areas : (F,) float
        Triangle areas [m^2]. Qhull's triangulation of a coplanar face may
        contain zero-area triangles; they have area 0 and contribute nothing.
    normals : (F, 3) float
        Unit outward normals.
    volume : float
        Enclosed volume [m^3], from the same triangles by the divergence
        theorem (V = 1/3 sum_f A_f n_f . xbar_f); checked against qhull's value.
    """

    vertices: np.ndarray
    facets: np.ndarray
    areas: np.ndarray
    normals: np.ndarray
    volume: float


def hull_of(centers) -> Hull:
    """Convex hull of ``centers`` (N, 3) [m] as an outward-oriented triangulation.

    Raises :class:`~amfe.errors.AmfeError` if the centres are fewer than four,
    not finite, or span no volume (coplanar or collinear).
    """
    x = np.asarray(centers, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3:
        raise AmfeError(f"hull_of: centres must have shape (N, 3), got {x.shape}")
    if x.shape[0] < 4:
        raise AmfeError(f"{_DEGENERATE_MSG} (only {x.shape[0]} particles; a volume needs at "
                        "least 4)")
    if not np.all(np.isfinite(x)):
        raise AmfeError("hull_of: the particle centres contain non-finite coordinates")

    # Work relative to the centroid: better conditioned cross products.
    origin = x.mean(axis=0)
    xr = x - origin
    extent = float(np.max(np.ptp(xr, axis=0)))
    if extent == 0.0:
        raise AmfeError(f"{_DEGENERATE_MSG} (all centres coincide)")
    try:
        # 'Qt' (triangulated output) is always on in scipy; coplanar points of
        # a lattice face are merged into one facet and re-triangulated.
        with signals_deferred():   # a signal inside qhull crashes it (amfe.signals)
            qh = ConvexHull(xr, qhull_options="Qt")
    except QhullError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise AmfeError(f"{_DEGENERATE_MSG} [qhull: {first}]") from None

    facets = np.array(qh.simplices, dtype=np.intp, copy=True)
    p0, p1, p2 = xr[facets[:, 0]], xr[facets[:, 1]], xr[facets[:, 2]]
    cross = np.cross(p1 - p0, p2 - p0)
    outward = qh.equations[:, :3]                        # unit, outward (qhull)
    flip = np.einsum("fi,fi->f", cross, outward) < 0.0
    facets[flip, 1], facets[flip, 2] = facets[flip, 2].copy(), facets[flip, 1].copy()
    cross[flip] *= -1.0

    twice_area = np.linalg.norm(cross, axis=1)
    areas = 0.5 * twice_area
    # Unit normal from the triangle itself (so that A n = cross / 2 exactly up
    # to round-off); zero-area triangles take qhull's facet normal.
    tiny = 1e-14 * extent**2
    good = twice_area > tiny
    normals = np.where(good[:, None], cross / np.where(good, twice_area, 1.0)[:, None], outward)

    centroid_f = (p0 + p1 + p2) / 3.0
    volume = float(np.sum(np.einsum("fi,fi->f", cross, centroid_f)) / 6.0)
    if not np.isfinite(volume) or volume <= 1e-12 * extent**3:
        raise AmfeError(f"{_DEGENERATE_MSG} (hull volume {volume:.3e} for extent {extent:.3e})")
    if abs(volume - qh.volume) > 1e-8 * max(volume, qh.volume):
        raise AmfeError(
            f"hull_of: the triangulated hull is not closed (volume {volume!r} from its "
            f"facets vs {qh.volume!r} from qhull); the centres are near-degenerate")
    return Hull(vertices=np.array(qh.vertices, dtype=np.intp), facets=facets,
                areas=areas, normals=normals, volume=volume)


# --------------------------------------------------------------------------- #
# Bagi strain and stress
# --------------------------------------------------------------------------- #
def bagi_strain(hull: Hull, displacements) -> np.ndarray:
    """Volume-averaged displacement gradient H (3, 3), H[i, j] = <d u_i / d x_j>.

    ``displacements`` (N, 3) [m] are the particle translations, indexed like the
    centres the hull was built from (only hull vertices are read). Returns the
    raw, NOT symmetrised gradient [-]; use :func:`symmetric` for the strain.

        H = (1/V) sum_f A_f ubar_f (x) n_f,

    ubar_f the mean of facet f's three vertex displacements, n_f its outward
    unit normal, A_f its area, V the hull volume.

    Why the boundary form: Bagi's strain is the volume-weighted mean of the
    gradients of the piecewise-linear interpolant on the Delaunay tetrahedra
    (the space cells) of the centres. By the divergence theorem that volume
    integral equals the hull-surface integral of u (x) n, and on each flat
    triangle the linear u integrates exactly to A_f ubar_f. The boundary form
    needs no tetrahedra at all: regular lattices produce zero-volume sliver
    tetrahedra whose edge matrices are singular, yet a flat sliver still
    contributes its share of sum u (x) n A when u is not affine on it. Dropping
    slivers, or inverting their singular edge matrices, gives a wrong average;
    the surface sum is exact and cheap (O(hull facets)).
    """
    u = np.asarray(displacements, dtype=float)
    if u.ndim != 2 or u.shape[1] != 3:
        raise AmfeError(f"bagi_strain: displacements must have shape (N, 3), got {u.shape}")
    if hull.facets.size and hull.facets.max() >= u.shape[0]:
        raise AmfeError(f"bagi_strain: the hull refers to particle {int(hull.facets.max())} "
                        f"but only {u.shape[0]} displacements were given")
    ubar = u[hull.facets].mean(axis=1)                   # (F, 3)
    an = hull.areas[:, None] * hull.normals              # (F, 3)
    return np.einsum("fi,fj->ij", ubar, an) / hull.volume


def bagi_stress(forces, positions, center, volume) -> np.ndarray:
    """Bagi average stress sigma (3, 3) [Pa], paper eq. 9.

        sigma_ij = (1/V) sum_b f_i^b (x_j^b - x_c_j),

    over the constrained particles b: ``forces`` (B, 3) [N] their reaction
    forces, ``positions`` (B, 3) [m] their centres, ``center`` (3,) [m] the
    reference point x_c, ``volume`` [m^3] V. Returned raw (not symmetrised):
    report :func:`asymmetry` first, then :func:`symmetric`. When the forces are
    in equilibrium (sum f = 0) the result does not depend on x_c.
    """
    f = np.asarray(forces, dtype=float)
    x = np.asarray(positions, dtype=float)
    xc = np.asarray(center, dtype=float).reshape(-1)
    if f.ndim != 2 or f.shape[1] != 3 or x.shape != f.shape:
        raise AmfeError(f"bagi_stress: forces and positions must both have shape (B, 3), "
                        f"got {f.shape} and {x.shape}")
    if xc.shape != (3,):
        raise AmfeError(f"bagi_stress: center must have shape (3,), got {xc.shape}")
    volume = float(volume)
    if not (np.isfinite(volume) and volume > 0.0):
        raise AmfeError(f"bagi_stress: volume must be positive and finite, got {volume!r}")
    return np.einsum("bi,bj->ij", f, x - xc) / volume


def symmetric(T) -> np.ndarray:
    """(T + T^T) / 2 of a square tensor or matrix (3x3 gradient, 6x6 stiffness)."""
    T = np.asarray(T, dtype=float)
    return 0.5 * (T + T.T)


def symmetrise(C) -> np.ndarray:
    """(C + C^T) / 2: the symmetric part of a 6x6 stiffness (caller's choice)."""
    return symmetric(C)


def asymmetry(T) -> float:
    """||T - T^T||_F / ||T||_F (0 for a zero tensor); report before symmetrising."""
    T = np.asarray(T, dtype=float)
    norm = float(np.linalg.norm(T))
    if norm == 0.0:
        return 0.0
    return float(np.linalg.norm(T - T.T)) / norm


# --------------------------------------------------------------------------- #
# Voigt notation and the six unit macro-strains
# --------------------------------------------------------------------------- #
def voigt(T) -> np.ndarray:
    """Stress-like Voigt vector (6,) of a (3, 3) tensor: (xx, yy, zz, yz, xz, xy).

    The shear entries are those of the symmetric part, (T_ij + T_ji) / 2, so a
    slightly asymmetric raw Bagi stress maps to its symmetric projection.
    """
    S = symmetric(T)
    if S.shape != (3, 3):
        raise AmfeError(f"voigt: expected a (3, 3) tensor, got {S.shape}")
    return S[_VI, _VJ].copy()


def voigt_strain(H) -> np.ndarray:
    """Strain-like Voigt vector (6,) of a displacement gradient H (3, 3).

    (eps_xx, eps_yy, eps_zz, gamma_yz, gamma_xz, gamma_xy) with engineering
    shears gamma_ij = 2 eps_ij = H_ij + H_ji.
    """
    v = voigt(H)
    v[3:] *= 2.0
    return v


def strain_from_voigt(e) -> np.ndarray:
    """Symmetric strain tensor (3, 3) of an engineering Voigt strain e (6,).

    eps_yz = eps_zy = e[3] / 2, eps_xz = e[4] / 2, eps_xy = e[5] / 2.
    """
    e = np.asarray(e, dtype=float).reshape(-1)
    if e.shape != (6,):
        raise AmfeError(f"strain_from_voigt: expected 6 components, got {e.shape}")
    eps = np.empty((3, 3))
    eps[_VI[:3], _VJ[:3]] = e[:3]
    eps[_VI[3:], _VJ[3:]] = 0.5 * e[3:]
    eps[_VJ[3:], _VI[3:]] = 0.5 * e[3:]
    return eps


def unit_strains() -> np.ndarray:
    """The six KUBC macro-strains (6, 3, 3): case k has Voigt strain = unit vector k.

    Cases 3-5 are unit engineering shears: case 3 has eps_yz = eps_zy = 0.5.
    """
    return np.stack([strain_from_voigt(e) for e in np.eye(6)])


# --------------------------------------------------------------------------- #
# Stiffness, compliance, engineering constants
# --------------------------------------------------------------------------- #
def stiffness(strains, stresses):
    """6x6 stiffness C from six (strain, stress) pairs, and its asymmetry.

    ``strains`` (6, 6): row k is case k's engineering Voigt strain [-];
    ``stresses`` (6, 6): row k is case k's Voigt stress [Pa]. With Eps and Sig
    holding the cases as columns, sigma = C eps for every case gives
    C = Sig Eps^-1 [Pa]. Returns ``(C, asym)`` with
    asym = ||C - C^T||_F / ||C||_F. Raises :class:`AmfeError` if the six strains
    do not span the strain space (condition number above 1e12).
    """
    E = np.asarray(strains, dtype=float)
    Sg = np.asarray(stresses, dtype=float)
    if E.shape != (6, 6) or Sg.shape != (6, 6):
        raise AmfeError("stiffness: strains and stresses must both be (6, 6), got "
                        f"{E.shape} and {Sg.shape}")
    if not (np.all(np.isfinite(E)) and np.all(np.isfinite(Sg))):
        raise AmfeError("stiffness: the strains or stresses contain non-finite values "
                        "(a load case failed?)")
    cond = float(np.linalg.cond(E))
    if not np.isfinite(cond) or cond > 1e12:
        raise AmfeError(f"stiffness: the six load cases' strains do not span the strain space "
                        f"(condition number {cond:.3e} > 1e12); C = Sig Eps^-1 is undefined")
    # C Eps = Sig with Eps = E^T, Sig = Sg^T  <=>  E C^T = Sg.
    C = np.linalg.solve(E, Sg).T
    return C, asymmetry(C)


def compliance_and_constants(C):
    """Compliance S = C^-1 (6, 6) [1/Pa] and the engineering constants.

    C (6, 6) [Pa] is inverted as given (symmetrise first with
    :func:`symmetrise` if wanted). Returns ``(S, props)``, props a dict with
    keys :data:`CONSTANT_KEYS`:

    Ex = 1/S11, Ey = 1/S22, Ez = 1/S33 [Pa];
    nu_yz = -S32/S22, nu_xz = -S31/S11, nu_xy = -S21/S11 [-]
    (nu_ij: lateral strain in j over axial strain in i under uniaxial stress in i);
    G_yz = 1/S44, G_xz = 1/S55, G_xy = 1/S66 [Pa].

    Raises :class:`AmfeError` if C has non-finite entries or is not positive
    definite (the eigenvalues of its symmetric part are in the message).
    """
    C = np.asarray(C, dtype=float)
    if C.shape != (6, 6):
        raise AmfeError(f"compliance_and_constants: C must be (6, 6), got {C.shape}")
    if not np.all(np.isfinite(C)):
        raise AmfeError("compliance_and_constants: C contains non-finite values")
    eig = np.linalg.eigvalsh(symmetric(C))
    if eig[0] <= 1e-12 * max(abs(eig[-1]), np.finfo(float).tiny):
        raise AmfeError("compliance_and_constants: C is not positive definite "
                        "(eigenvalues of its symmetric part: "
                        f"{np.array2string(eig, precision=4)}); "
                        "the frame is unstable or a load case is wrong")
    S = np.linalg.inv(C)
    props = {
        "Ex": 1.0 / S[0, 0],
        "Ey": 1.0 / S[1, 1],
        "Ez": 1.0 / S[2, 2],
        "nu_yz": -S[2, 1] / S[1, 1],
        "nu_xz": -S[2, 0] / S[0, 0],
        "nu_xy": -S[1, 0] / S[0, 0],
        "G_yz": 1.0 / S[3, 3],
        "G_xz": 1.0 / S[4, 4],
        "G_xy": 1.0 / S[5, 5],
    }
    return S, {k: float(props[k]) for k in CONSTANT_KEYS}


def dual_corrected(work, cross, sign):
    """(work + sign D, stats): a condition's (6, 6) loads' work to second order.

    cross: None or [D] (one group), D_IJ = U_I . r_J the solutions against the
    true residuals; sign +1 where the average is F_I . U_J (SUBC), -1 where it
    is W0 - F_I . U_J (periodic); the reasoning is in amfe.solvers.correction.
    stats: {"correction": ||D|| / ||work||}, or {} without D.
    """
    D = (cross or [None])[0]
    if D is None:
        return work, {}
    return work + sign * D, {"correction": float(np.linalg.norm(D) / np.linalg.norm(work))}


def box_center(centers) -> np.ndarray:
    """Centre (3,) [m] of the axis-aligned bounding box of ``centers`` (N, 3)."""
    x = np.asarray(centers, dtype=float)
    return 0.5 * (x.min(axis=0) + x.max(axis=0))
