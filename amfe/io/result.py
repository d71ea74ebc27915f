"""A homogenization result as plain data: :class:`Result` (and its :class:`Fields`).

``Result.to_dict()`` is the JSON layout of docs/model.md, section 6 (the keys
`amfe homogenize -o` writes), plus ``schema_version``. Arrays are numpy;
units are SI (Pa, 1/Pa, m^3, m, N).
"""
from dataclasses import dataclass, field, fields as dc_fields

import numpy as np

from amfe.errors import AmfeError
from amfe.io.atomic import write_json
from amfe.io.vtu import write_load_cases
from amfe.vocab import CASE_NAMES, CONSTANT_NAMES, CONSTANT_UNITS

#: Version of the JSON layout; bumped when a key changes meaning or goes away.
SCHEMA_VERSION = 2


@dataclass
class Fields:
    """Per-case fields of the kept (load-carrying) particles, per unit macro-strain.

    particle_id (n,) int: each kept particle's index in the input bed;
    centers (n, 3) [m], radii (n,) [m] of the kept particles;
    bonds (M, 2) int: the bonds' two particles as rows of the kept arrays;
    displacement (6, n, 3) [m], rotation (6, n, 3) [rad]: per case
    (Voigt order xx, yy, zz, yz, xz, xy), per unit strain;
    axial_force (6, M) [N], shear_force (6, M) [N, magnitude],
    moment (6, M) [N m, magnitude]: per bond, per case; shift (M, 3) int, on a
    periodic frame only: bond k joins the image of its second particle shifted
    by shift[k] periods (docs/model.md, section 9).
    """

    particle_id: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    bonds: np.ndarray
    displacement: np.ndarray
    rotation: np.ndarray
    axial_force: np.ndarray
    shear_force: np.ndarray
    moment: np.ndarray
    case_names: tuple = CASE_NAMES
    shift: np.ndarray = None


def write_fields_vtu(directory, f):
    """One VTU per load case of :class:`Fields` ``f`` and cases.pvd in ``directory``.

    On a periodic frame every particle is drawn once, at its place in the box,
    and the bonds that cross a face are left out (drawn between the two
    particles they would span the box).
    """
    drawn = np.ones(len(f.bonds), bool) if f.shift is None else ~np.any(f.shift != 0, axis=1)
    cases = [{"displacement": f.displacement[k], "rotation": f.rotation[k],
              "axial_force": f.axial_force[k][drawn], "shear_force": f.shear_force[k][drawn],
              "moment": f.moment[k][drawn]} for k in range(len(f.case_names))]
    return write_load_cases(directory, f.centers, f.radii, f.bonds[drawn], cases,
                            names=list(f.case_names))


@dataclass
class Result:
    """Effective elastic constants of one bed, and how they were obtained.

    properties: {name: value} for Ex, Ey, Ez [Pa], nu_yz, nu_xz, nu_xy [-],
    G_yz, G_xz, G_xy [Pa] (nu_ij = -S_ji / S_ii); C (6, 6) [Pa] and S (6, 6)
    [1/Pa] in Voigt order with engineering shear; volume [m^3]; n_particles
    (input), n_removed, n_bonds (kept); bc; ranks; solver: the solver record;
    fields: :class:`Fields` when asked for (``fields=True``); extra: any
    other key of the JSON layout (n_capped, diagnostics, input, ...).

    The constants are also attributes: ``result.Ex``.
    """

    properties: dict
    C: np.ndarray
    S: np.ndarray
    volume: float
    n_particles: int
    n_removed: int
    n_bonds: int
    bc: str
    ranks: int
    solver: dict
    extra: dict = field(default_factory=dict)
    fields: Fields = field(default=None, repr=False)
    schema_version: int = SCHEMA_VERSION

    @classmethod
    def from_dict(cls, d, fields=None):
        """A Result from the dict :func:`amfe.solvers.driver.homogenize_bed` returns."""
        names = {f.name for f in dc_fields(cls)} - {"extra", "fields", "schema_version"}
        kw = {k: d[k] for k in names}
        kw["C"], kw["S"] = np.asarray(d["C"], float), np.asarray(d["S"], float)
        extra = {k: v for k, v in d.items() if k not in names and k != "schema_version"}
        return cls(**kw, extra=extra, fields=fields)

    def __getattr__(self, name):
        if name in CONSTANT_NAMES:
            return self.properties[name]
        raise AttributeError(f"{type(self).__name__!s} has no attribute {name!r}")

    def __dir__(self):
        return sorted(set(super().__dir__()) | set(CONSTANT_NAMES))

    def to_dict(self):
        """The JSON layout (plain lists and numbers), with ``schema_version``."""
        d = {"schema_version": self.schema_version, "properties": dict(self.properties),
             "C": np.asarray(self.C).tolist(), "S": np.asarray(self.S).tolist(),
             "volume": float(self.volume), "n_particles": int(self.n_particles),
             "n_removed": int(self.n_removed), "n_bonds": int(self.n_bonds), "bc": self.bc,
             "ranks": int(self.ranks), "solver": self.solver}
        d.update(self.extra)
        return d

    def to_json(self, path):
        """Write :meth:`to_dict` to ``path`` atomically (a reader never sees half a file)."""
        write_json(path, self.to_dict())

    def write_vtu(self, directory):
        """One VTU per load case and cases.pvd in ``directory`` (needs ``fields=True``)."""
        if self.fields is None:
            raise AmfeError("this result holds no fields: homogenize with fields=True "
                            "to write VTU files")
        return write_fields_vtu(directory, self.fields)

    def __repr__(self):
        lines = [f"Result(bc={self.bc!r}, {self.n_particles} particles "
                 f"({self.n_removed} removed), {self.n_bonds} bonds, volume {self.volume:.4g} m^3,"]
        for name in CONSTANT_NAMES:
            value = self.properties[name]
            unit = CONSTANT_UNITS[name]
            lines.append(f"  {name:6s} = {value / 1e9:10.4f} GPa" if unit == "Pa"
                         else f"  {name:6s} = {value:10.4f}")
        s = self.solver
        lines.append(f"  solver: {s.get('ksp_type')}+{s.get('pc_type')}, rtol {s.get('rtol')}, "
                     f"iterations {s.get('iterations')}"
                     + (", with fields)" if self.fields is not None else ")"))
        return "\n".join(lines)
