"""ParaView files of the load cases: ``case_<name>.vtu`` each, ``cases.pvd`` and ``cases.json``.

The case files are VTK XML UnstructuredGrids written by meshio (docs/viewing.md);
amfe writes no VTK ``DataArray`` itself. ParaView's Tube filter wants PolyData,
so the view script puts Extract Surface before it (amfe/viz/amfe_view_pv.py).

Layout of ``case_<name>.vtu`` (SI; the unit ends each array's name)
------------------------------------------------------------------
Points: the kept (load-carrying) particles' centres [m] in input order. Cells:
one 2-point line per bond, running from particle i to particle j (on a
periodic frame, not the bonds across a face: they would span the box). No vertex
cells: every kept particle has a bond, and vertex cells would make every bond
array carry fake values on them (zeros that spoil colour ranges).

Point data (:data:`POINT_ARRAYS`): ``particle_id``, ``radius_m``, ``boundary``,
``displacement_m`` (the first vector array: Warp By Vector picks it), ``rotation_rad``.
Cell data (:data:`CELL_ARRAYS`): ``i``, ``j`` (input ids), ``a_star``,
``force_i_N``, ``moment_i_Nm``, ``axial_force_N``, ``shear_force_N``,
``torsion_Nm``, ``bending_moment_Nm``. Ids are Int32 (Int64 for beds of 2**31
particles or more), ``boundary`` UInt8, the rest Float64.

meshio 5.3.5 writes no field data: the case label, macro-strain, warp factor,
units, boundary condition, ... are in ``cases.json`` (:mod:`amfe.io.pvd`).

Binary, uncompressed (:data:`COMPRESSION`): meshio's zlib compresses every
array of a file at one level, and on the paper's bed (295 583 particles,
1.7 M bonds) it took 5 to 6 times as long as storing (3.6 times amfe 0.2's
writer, whose budget is 1.5) for files 21 % smaller; the float64 fields hardly
compress (run/bench/vtu.py, docs/benchmarks.md).

Atomicity: everything is checked before a file is touched. The directory is
locked (:class:`amfe.io.vtuset.SetLock`), an old ``cases.pvd`` is removed first,
each case is written atomically (:func:`amfe.io.atomic.atomic_write`; a symbolic
link at its name is replaced, its target never written), then ``cases.json``,
``cases.pvd`` last, and the case files that the earlier set's ``cases.json`` or
``cases.pvd`` listed and the new one does not are removed; nothing else
(:mod:`amfe.io.vtuset`). So ``cases.pvd`` exists if and only if the set beside
it is complete.
"""
import json
import os
import re

import numpy as np

from amfe.errors import AmfeError
from amfe.io.atomic import atomic_write, fsync_dir
from amfe.io.pvd import PVD_NAME, SIDECAR_NAME, case_fields, pvd_text
from amfe.io.vtuset import SetLock, listed_files, unlink_links
from amfe.version import __version__

COMPRESSION = None
"""meshio's compressor for the case files: None (stored) or "zlib" (see the module doc)."""
WARP_SHARE = 0.05
"""Largest displacement drawn, as a share of the largest side of the points' box."""

POINT_ARRAYS = {
    "particle_id": ("1", "index of the particle in the input bed file"),
    "radius_m": ("m", "particle radius"),
    "boundary": ("1", "1: translations prescribed in this load case (boundary particle)"),
    "displacement_m": ("m", "particle displacement per unit macro-strain"),
    "rotation_rad": ("rad", "particle rotation (axial vector) per unit macro-strain"),
}
CELL_ARRAYS = {
    "i": ("1", "input id of the bond's first particle (the line runs i -> j)"),
    "j": ("1", "input id of the bond's second particle"),
    "a_star": ("1", "contact radius over effective radius, a / R_eff (geometric)"),
    "force_i_N": ("N", "force of the bond on particle i (on j: the opposite)"),
    "moment_i_Nm": ("N m", "moment of the bond on particle i about i's centre"),
    "axial_force_N": ("N", "normal spring force, positive in tension"),
    "shear_force_N": ("N", "magnitude of the shear force at the contact point"),
    "torsion_Nm": ("N m", "torsion couple on i about e = (x_j - x_i) / L, signed"),
    "bending_moment_Nm": ("N m", "magnitude of the bending couple"),
}
END_CONVENTION = ("force_i_N and moment_i_Nm act on particle i (cell array i); particle j "
                  "gets -force_i_N and L e x force_i_N - moment_i_Nm about its own centre, "
                  "with e = (x_j - x_i) / L and L = |x_j - x_i|")
_SAFE_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")
_VOIGT = (("eps_xx", 0, 0), ("eps_yy", 1, 1), ("eps_zz", 2, 2), ("gamma_yz", 1, 2),
          ("gamma_xz", 0, 2), ("gamma_xy", 0, 1))


def case_filename(name):
    """File name of the load case called ``name``: ``case_<name>.vtu``."""
    return f"case_{name}.vtu"


def warp_factor(points, displacement, share=WARP_SHARE):
    """Scale that draws the largest displacement as ``share`` of the box's largest side.

    Parameters
    ----------
    points : ndarray (N, 3) [m]
    displacement : ndarray (N, 3) [m]
    share : float

    Returns
    -------
    float
        The factor; 1.0 when nothing moves or the points span nothing.
    """
    if len(points) == 0:
        return 1.0
    side = float(np.ptp(points, axis=0).max())
    umax = float(np.sqrt(np.einsum("ij,ij->i", displacement, displacement).max()))
    return share * side / umax if umax > 0 and side > 0 else 1.0


def voigt_of(eps):
    """Engineering Voigt vector (6,) of a strain tensor (3, 3)."""
    return np.array([(1.0 if i == j else 2.0) * eps[i, j] for _, i, j in _VOIGT])


def case_label(name, eps=None, sigma=None):
    """``"yz: gamma_yz = 1"``: the case's name and its non-zero Voigt strains.

    With ``sigma`` [Pa] instead of ``eps``, its stresses: ``"yz: sigma_yz = 2.1e+11 Pa"``.
    """
    if eps is None:
        comps = [f"sigma_{sym[-2:]} = {sigma[i, j]:.3g} Pa" for sym, i, j in _VOIGT
                 if sigma[i, j] != 0]
    else:
        comps = [f"{sym} = {v:g}" for (sym, _, _), v in zip(_VOIGT, voigt_of(eps)) if v != 0]
    return f"{name}: " + (", ".join(comps) if comps else "no load")


def write_fields_vtu(directory, fields, field_data=None):
    """Write one ``case_<name>.vtu`` per load case of ``fields``, ``cases.json`` and ``cases.pvd``.

    Parameters
    ----------
    directory : str or path-like
        Created (with parents) if missing.
    fields : amfe.io.fields.Fields
        SI arrays; every value must be finite.
    field_data : dict, optional
        More keys for ``cases.json`` (JSON-serialisable: str, numbers, lists).

    Returns
    -------
    list of str
        The case files' paths in case order, then the ``.pvd``'s.

    Raises
    ------
    AmfeError
        Bad names, shapes or non-finite values (nothing is touched then), or
        a failed write (then no ``cases.pvd`` is left).
    """
    import meshio

    names = _check(fields)
    arrays = {**POINT_ARRAYS, **CELL_ARRAYS}
    stress = fields.macro_strain is None
    # A periodic frame's bonds across a face would span the box: left out.
    drawn = np.ones(len(fields.bonds), bool) if fields.shift is None else \
        ~np.any(np.asarray(fields.shift) != 0, axis=1)
    sidecar = {"amfe_version": __version__, "bc": fields.bc,
               "units": {k: u for k, (u, _) in arrays.items()},
               "descriptions": {k: d for k, (_, d) in arrays.items()},
               "end_convention": END_CONVENTION,
               "per_unit_strain": "displacements, rotations and loads are per unit "
                                  + ("macro-stress of E (the particles' modulus)" if stress
                                     else "macro-strain"),
               "bonds_not_drawn": int((~drawn).sum())}
    sidecar.update(field_data or {})
    # Int32 ids halve their share of the file; VTK reads either.
    pid = np.asarray(fields.particle_id, dtype=np.int64)
    ids = np.int32 if len(pid) == 0 or pid.max() < 2 ** 31 - 1 else np.int64
    pid = pid.astype(ids)
    lines = np.asarray(fields.bonds)[drawn].astype(ids)
    static_cells = {"i": pid[lines[:, 0]], "j": pid[lines[:, 1]],
                    "a_star": np.asarray(fields.a_star, dtype=float)[drawn]}
    cases = []
    for k, nm in enumerate(names):
        disp = np.asarray(fields.displacement[k], dtype=float)
        entry = {"file": case_filename(nm), "case_name": nm}
        if stress:
            sig = np.asarray(fields.macro_stress[k], dtype=float)
            entry.update(case_label=case_label(nm, sigma=sig), macro_stress_Pa=sig.ravel().tolist())
        else:
            eps = np.asarray(fields.macro_strain[k], dtype=float)
            entry.update(case_label=case_label(nm, eps), macro_strain=eps.ravel().tolist(),
                         macro_strain_voigt=voigt_of(eps).tolist())
        entry["warp_factor"] = warp_factor(fields.centers, disp)
        cases.append(entry)
    sidecar["cases"] = cases

    def write_case(k, path):
        pd = {"particle_id": pid, "radius_m": np.asarray(fields.radii, dtype=float),
              "boundary": np.asarray(fields.boundary[k]).astype(np.uint8),
              "displacement_m": np.asarray(fields.displacement[k], dtype=float),
              "rotation_rad": np.asarray(fields.rotation[k], dtype=float)}
        cd = {"force_i_N": fields.force[k], "moment_i_Nm": fields.moment[k],
              "axial_force_N": fields.axial_force[k], "shear_force_N": fields.shear_force[k],
              "torsion_Nm": fields.torsion[k], "bending_moment_Nm": fields.bending_moment[k]}
        cd = {**static_cells, **{key: np.asarray(v, dtype=float)[drawn] for key, v in cd.items()}}
        mesh = meshio.Mesh(np.asarray(fields.centers, dtype=float), [("line", lines)],
                           point_data=pd, cell_data={key: [v] for key, v in cd.items()})
        meshio.vtu.write(path, mesh, binary=True, compression=COMPRESSION,
                         header_type="UInt64")

    try:
        text = json.dumps(sidecar, indent=1) + "\n"
    except (TypeError, ValueError) as exc:       # before any file is touched
        raise AmfeError(f"field_data must be JSON-serialisable: {exc}") from None
    return _write_set(os.fspath(directory), write_case, names, text)


def _check(f):
    """Validate ``f`` before anything is written; returns the case names."""
    names = list(f.case_names)
    if not names or len(set(names)) != len(names) or \
            not all(isinstance(s, str) and _SAFE_NAME.match(s) for s in names):
        raise AmfeError(f"case names must be distinct, non-empty strings of letters, digits, "
                        f"'_' and '-'; got {names}")
    n, m, k = len(f.particle_id), len(f.bonds), len(names)
    load = "macro_strain" if f.macro_strain is not None else "macro_stress"
    shapes = {"centers": (n, 3), "radii": (n,), "bonds": (m, 2), "a_star": (m,),
              "boundary": (k, n), load: (k, 3, 3), "displacement": (k, n, 3),
              "rotation": (k, n, 3), "force": (k, m, 3), "moment": (k, m, 3),
              "axial_force": (k, m), "shear_force": (k, m), "torsion": (k, m),
              "bending_moment": (k, m)}
    if f.shift is not None:
        shapes["shift"] = (m, 3)
    for key, shape in shapes.items():
        arr = np.asarray(getattr(f, key))
        if arr.shape != shape:
            raise AmfeError(f"fields.{key} has shape {arr.shape}, {shape} expected "
                            f"({n} particles, {m} bonds, {k} cases)")
        if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
            raise AmfeError(f"fields.{key} has non-finite values; nothing was written")
    pid = np.asarray(f.particle_id)
    if pid.dtype.kind not in "iu" or (n and pid.min() < 0) or np.unique(pid).size != n:
        raise AmfeError("fields.particle_id must hold distinct non-negative integers")
    bonds = np.asarray(f.bonds)
    if m and (bonds.min() < 0 or bonds.max() >= n or np.any(bonds[:, 0] == bonds[:, 1])):
        raise AmfeError(f"fields.bonds must join two different particles of 0..{n - 1}")
    return names


def _write_set(directory, write_case, names, sidecar_text):
    try:
        os.makedirs(directory, exist_ok=True)
    except OSError as exc:
        raise AmfeError(f"cannot create the output directory {directory}: {exc}") from None
    pvd = os.path.join(directory, PVD_NAME)
    sidecar = os.path.join(directory, SIDECAR_NAME)
    final = [os.path.join(directory, case_filename(nm)) for nm in names]
    with SetLock(directory):                     # one writer per directory
        previous = listed_files(directory)       # before its cases.pvd goes
        try:
            if os.path.lexists(pvd):             # no stale collection outlives a failed write
                os.remove(pvd)
            unlink_links(final + [sidecar])      # a link is replaced, its target never written
            for k, path in enumerate(final):
                atomic_write(path, lambda tmp, k=k: write_case(k, tmp), by_name=True)
            atomic_write(sidecar, lambda fh: fh.write(sidecar_text.encode()))
            text = pvd_text([os.path.basename(p) for p in final], names).encode()
            atomic_write(pvd, lambda fh: fh.write(text))
        except OSError as exc:
            raise AmfeError(f"writing the load-case files in {directory} failed ({exc}); no "
                            f"{PVD_NAME} was left, so no partial set looks complete") from None
        keep = {os.path.basename(p) for p in final}
        for entry in previous - keep:            # the earlier set's own files, nothing else
            try:
                os.remove(os.path.join(directory, entry))
            except OSError:
                pass
        fsync_dir(directory)
    return final + [pvd]


def read_case(path):
    """One case file as numpy arrays (meshio's read), with what ``cases.json`` says of it.

    Returns
    -------
    dict
        ``points`` (N, 3) [m], ``lines`` (M, 2) int64 point indices, ``point_data``
        {name: (N,) or (N, k)}, ``cell_data`` {name: (M,) or (M, k)}, and
        ``field_data``: :func:`amfe.io.pvd.case_fields` ({} without a sidecar).

    Raises
    ------
    AmfeError
        Not a VTU file, or cells other than 2-point lines.
    """
    import meshio

    path = os.fspath(path)
    try:
        mesh = meshio.vtu.read(path)
    except Exception as exc:                     # meshio raises ReadError, KeyError, ...
        raise AmfeError(f"cannot read {path} as a VTU file: {exc}") from None
    if any(block.type != "line" for block in mesh.cells) or len(mesh.cells) > 1:
        raise AmfeError(f"{path}: only 2-point line cells are read, found "
                        + ", ".join(b.type for b in mesh.cells))
    lines = mesh.cells[0].data if mesh.cells else np.zeros((0, 2))
    return {"points": np.asarray(mesh.points, dtype=float),
            "lines": np.asarray(lines, dtype=np.int64).reshape(-1, 2),
            "point_data": dict(mesh.point_data),
            "cell_data": {k: v[0] for k, v in mesh.cell_data.items()},
            "field_data": case_fields(path)}
