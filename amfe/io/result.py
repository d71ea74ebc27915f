"""A homogenization result as plain data: :class:`Result` (and its :class:`Fields`).

``Result.to_dict()`` is the JSON layout of docs/model.md, section 6 (the keys
`amfe homogenize -o` writes): the header of :mod:`amfe.io.result_meta` first
(schema version, input and its hash, material, box, units, counts,
conventions), then the constants and the solver record; it follows the
shipped JSON Schema. Arrays are numpy; units are SI (Pa, 1/Pa, m^3, m, N).
"""
import json
import os
from dataclasses import dataclass, field
from dataclasses import fields as dc_fields

import numpy as np

from amfe.errors import AmfeError
from amfe.io.atomic import write_json
from amfe.io.fields import Fields
from amfe.io.result_meta import HEADER_KEYS, SCHEMA_VERSION
from amfe.io.vtu import write_fields_vtu
from amfe.vocab import CONSTANT_NAMES, CONSTANT_UNITS

__all__ = ["Result", "Fields", "SCHEMA_VERSION"]


@dataclass
class Result:
    """Effective elastic constants of one bed, and how they were obtained.

    properties: {name: value} for Ex, Ey, Ez [Pa], nu_yz, nu_xz, nu_xy [-],
    G_yz, G_xz, G_xy [Pa] (nu_ij = -S_ji / S_ii); C (6, 6) [Pa] and S (6, 6)
    [1/Pa] in Voigt order with engineering shear; volume [m^3]; n_particles
    (input), n_removed, n_bonds (kept); bc; ranks; solver: the solver record;
    fields: :class:`Fields` when asked for (``fields=True``); extra: any
    other key of the JSON layout (the header: input, material, box, units,
    counts, ...; n_capped, diagnostics, vtk, ...).

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
    def from_dict(cls, d: dict, fields: Fields | None = None) -> "Result":
        """A Result from the dict :func:`amfe.solvers.driver.homogenize_bed` returns."""
        names = {f.name for f in dc_fields(cls)} - {"extra", "fields", "schema_version"}
        kw = {k: d[k] for k in names}
        kw["C"], kw["S"] = np.asarray(d["C"], float), np.asarray(d["S"], float)
        extra = {k: v for k, v in d.items() if k not in names and k != "schema_version"}
        return cls(**kw, extra=extra, fields=fields)

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> "Result":
        """The Result that :meth:`to_json` (or ``amfe homogenize -o``) wrote to ``path``.

        AmfeError for a file of another kind (``--bc all``: :func:`amfe.read_result`).
        """
        data = load_json(path)
        if data.get("bc") == "all" or data.get("command") == "predict":
            kind = "--bc all" if data.get("bc") == "all" else "predict"
            raise AmfeError(f"{os.fspath(path)} holds the results of {kind}, not one Result: "
                            "read it with amfe.read_result")
        try:
            return cls.from_dict(data)
        except (KeyError, TypeError, ValueError) as exc:
            raise AmfeError(f"{os.fspath(path)} is not a complete amfe result "
                            f"({type(exc).__name__}: {exc})") from None

    def __getattr__(self, name: str) -> float:
        if name in CONSTANT_NAMES:
            return self.properties[name]
        raise AttributeError(f"{type(self).__name__!s} has no attribute {name!r}")

    def __dir__(self) -> list[str]:
        return sorted(set(super().__dir__()) | set(CONSTANT_NAMES))

    def to_dict(self) -> dict:
        """The JSON layout (plain lists and numbers): the header, then the results."""
        d = {"schema_version": self.schema_version}
        d.update((k, self.extra[k]) for k in HEADER_KEYS if k in self.extra)
        d.update({"properties": dict(self.properties),
                  "C": np.asarray(self.C).tolist(), "S": np.asarray(self.S).tolist(),
                  "volume": float(self.volume), "n_particles": int(self.n_particles),
                  "n_removed": int(self.n_removed), "n_bonds": int(self.n_bonds),
                  "bc": self.bc, "ranks": int(self.ranks), "solver": self.solver})
        d.update((k, v) for k, v in self.extra.items() if k not in d)
        return d

    def to_json(self, path: str | os.PathLike) -> None:
        """Write :meth:`to_dict` to ``path`` atomically (a reader never sees half a file).

        AmfeError, naming the path, for a directory, a path that is not a
        file name, and one that cannot be written (no permission, no such
        directory and none can be made, a full disk).
        """
        if not isinstance(path, (str, os.PathLike)) or os.fspath(path) in ("", b""):
            raise AmfeError(f"Result.to_json: path must be a file name (str or path-like), got "
                            f"{type(path).__name__} {path!r}")
        if os.path.isdir(path):
            raise AmfeError(f"Result.to_json: {os.fspath(path)} is a directory; give a file name "
                            f"(e.g. {os.path.join(os.fspath(path), 'result.json')})")
        try:
            write_json(path, self.to_dict())
        except OSError as exc:
            raise AmfeError(f"cannot write {os.fspath(path)}: {exc.strerror or exc}") from None

    def write_vtu(self, directory: str | os.PathLike) -> list[str]:
        """ParaView files: ``case_<name>.vtu`` per load case, ``cases.json`` and ``cases.pvd``.

        Needs ``fields=True``; the layout is in :mod:`amfe.io.vtu` and
        docs/viewing.md. Returns the case files' paths, the ``.pvd`` last.
        """
        if self.fields is None:
            raise AmfeError("this result holds no fields: homogenize with fields=True "
                            "to write ParaView files")
        return write_fields_vtu(directory, self.fields)

    #: amfe 0.2's name of :meth:`write_vtu` (it wrote ``.vtp`` files then).
    write_vtp = write_vtu

    def __repr__(self) -> str:
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


def load_json(path: str | os.PathLike) -> dict:
    """The JSON object of a result file amfe wrote; AmfeError naming the file for one that is
    missing, not JSON, or without a schema_version (not amfe's)."""
    try:
        with open(path) as f:
            data = json.load(f)
    except FileNotFoundError:
        raise AmfeError(f"{os.fspath(path)} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise AmfeError(f"cannot read {os.fspath(path)} as JSON: {exc}") from None
    if not isinstance(data, dict) or "schema_version" not in data:
        raise AmfeError(f"{os.fspath(path)} is not a result amfe wrote (no schema_version)")
    return data
