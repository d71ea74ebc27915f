"""Per-case fields of a solved frame as plain SI arrays: :class:`Fields` and :func:`frame_fields`.

What ``homogenize(..., fields=True)`` returns and what the ParaView files
(:mod:`amfe.io.vtu`, docs/viewing.md) hold. Particles are the kept
(load-carrying) ones in input order, so ``particle_id`` is increasing and
``centers`` equals ``bed.centers[particle_id]`` bit for bit when the input
arrays are given. Bond loads are those on particle i's end (the bond's first
particle, the line runs i -> j); j's end follows from the bond's equilibrium
(:func:`amfe.model.element.bond_end_loads`). Everything is per unit
macro-strain (SUBC: per unit macro-stress of E, the particles' modulus): a
frame under eps_xx = 1 doubles its length, so views scale it.

On a periodic frame (docs/model.md, section 9) a bond may join particle i to
an image of j one period away (``shift``); its loads include the jump of the
macro-strain across the face, and the ParaView files leave it out (it would
span the box).
"""
from dataclasses import dataclass

import numpy as np

from amfe.model.averages import unit_strains
from amfe.model.conditions import get_condition
from amfe.model.element import bond_end_loads
from amfe.model.periodic import bond_jumps
from amfe.model.subc import unit_stresses
from amfe.vocab import CASE_NAMES


@dataclass
class Fields:
    """The displacements, rotations and bond loads of every load case, SI units.

    n kept particles (input order), M bonds, K load cases (normally six, Voigt
    order xx, yy, zz, yz, xz, xy).

    Attributes
    ----------
    particle_id : ndarray (n,) int64
        Each particle's index in the input bed (increasing).
    centers : ndarray (n, 3) [m]
    radii : ndarray (n,) [m]
    bonds : ndarray (M, 2) int64
        The two ends (i, j) of each bond as rows of the particle arrays.
    a_star : ndarray (M,) [-]
        Contact radius over effective radius, a / R_eff (geometric, before any cap).
    boundary : ndarray (K, n) bool
        Where the boundary condition acts in the case: translations prescribed
        (kubc, mixed, a pin), loads applied (subc's boundary layer), or a bond
        across a face (periodic). Everywhere else the bond loads balance.
    macro_strain : ndarray (K, 3, 3) [-], or None
        The macro-strain each case applies (mixed: the grips' nominal strain;
        None for subc, whose cases are stresses).
    displacement, rotation : ndarray (K, n, 3) [m], [rad]
        Per unit macro-strain; rotations are axial vectors.
    force, moment : ndarray (K, M, 3) [N], [N m]
        Force and moment (about i's centre) the bond puts on particle i.
    axial_force : ndarray (K, M) [N]
        Normal spring force, positive in tension.
    shear_force : ndarray (K, M) [N]
        Magnitude of the shear force at the contact point.
    torsion : ndarray (K, M) [N m]
        Torsion couple on i about e = (x_j - x_i) / |x_j - x_i|, signed.
    bending_moment : ndarray (K, M) [N m]
        Magnitude of the bending couple.
    case_names : tuple of str
    bc : str
        Boundary condition of the cases (docs/model.md, sections 5 and 9).
    macro_stress : ndarray (K, 3, 3) [Pa], or None
        The macro-stress each case applies (subc only).
    shift : ndarray (M, 3) int, or None
        Periodic frames only: bond k joins the image of its second particle
        shifted by ``shift[k]`` periods.
    """

    particle_id: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    bonds: np.ndarray
    a_star: np.ndarray
    boundary: np.ndarray
    macro_strain: np.ndarray
    displacement: np.ndarray
    rotation: np.ndarray
    force: np.ndarray
    moment: np.ndarray
    axial_force: np.ndarray
    shear_force: np.ndarray
    torsion: np.ndarray
    bending_moment: np.ndarray
    case_names: tuple = CASE_NAMES
    bc: str = "kubc"
    macro_stress: np.ndarray = None
    shift: np.ndarray = None

    @property
    def n_particles(self) -> int:
        return int(self.particle_id.size)

    @property
    def n_bonds(self) -> int:
        return int(self.bonds.shape[0])


def frame_fields(frame, u, groups, bc="kubc", centers=None, radii=None, strains=None):
    """The :class:`Fields` of a solved frame.

    Parameters
    ----------
    frame : amfe.model.frame.Frame
        The (non-dimensional) frame that was solved.
    u : ndarray (K, n, 6)
        Its DOFs per case, frame order, non-dimensional.
    groups : list of amfe.model.loadcase.Group
        The groups that were solved (their cases in the order of ``u``): they
        give the case names and the particles with prescribed translations.
    bc : str
        Name of the boundary condition.
    centers : ndarray (N, 3) [m], optional; radii : ndarray (N,) [m], optional
        The input bed: points and radii are then its values bit for bit
        (``frame.centers * length_scale`` can differ in the last bit).
    strains : ndarray (K, 3, 3), optional
        Macro-strain of each case; default the six unit strains (none for subc).

    Returns
    -------
    Fields
    """
    u = np.asarray(u)
    L, F = frame.length_scale, frame.force_scale
    order = np.argsort(frame.kept, kind="stable")          # input order
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    ids = frame.kept[order].astype(np.int64)
    strains = unit_strains() if strains is None else np.asarray(strains, dtype=float)
    b = frame.bonds
    uj = u[:, b.j].copy()
    if frame.shift is not None:          # the image of j moves by the jump eps (s L) more
        uj[:, :, :3] += bond_jumps(frame, strains)
    springs = (frame.k_n, frame.k_t, frame.kappa_n, frame.kappa_t)
    loads = [bond_end_loads(b.normal, b.d_i, b.d_j, springs, uk[b.i], ujk)
             for uk, ujk in zip(u, uj)]

    def stack(key, scale):
        return np.array([d[key] * scale for d in loads])

    subc = get_condition(bc).loads == "stress"   # the cases apply macro-stresses
    return Fields(
        particle_id=ids,
        centers=(frame.centers[order] * L + frame.origin if centers is None
                 else np.asarray(centers, float)[ids]),
        radii=frame.radii[order] * L if radii is None else np.asarray(radii, float)[ids],
        bonds=np.stack([rank[b.i], rank[b.j]], axis=1).astype(np.int64),
        a_star=np.asarray(b.a_star, dtype=float),
        boundary=acted_on(frame, groups)[:, order],
        macro_strain=None if subc else strains,
        macro_stress=unit_stresses() * frame.stress_scale if subc else None,
        displacement=u[:, order, :3] * L, rotation=u[:, order, 3:].copy(),
        force=stack("force_i", F), moment=stack("moment_i", F * L),
        axial_force=stack("axial", F), shear_force=stack("shear", F),
        torsion=stack("torsion", F * L), bending_moment=stack("bending", F * L),
        case_names=tuple(n for g in groups for n in g.names), bc=bc, shift=frame.shift)


def acted_on(frame, groups):
    """(K, n) bool, frame order: where each case's boundary condition acts (see Fields)."""
    out = []
    for g in groups:
        for k in range(len(g.names)):
            mask = g.fixed[:, :3].any(axis=1)
            if g.forces is not None:
                mask = mask | np.any(np.asarray(g.forces[k]) != 0, axis=1)
            out.append(mask)
    out = np.array(out)
    if frame.shift is not None:          # bonds across a face are not drawn
        across = np.any(frame.shift != 0, axis=1)
        out[:, frame.bonds.i[across]] = True
        out[:, frame.bonds.j[across]] = True
    return out
