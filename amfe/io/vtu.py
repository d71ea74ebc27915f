"""ParaView output of the six load cases (docs/model.md, section 6).

One XML UnstructuredGrid file (``.vtu``, binary, zlib-compressed, written by
meshio) per load case, plus a ``cases.pvd`` collection that opens them all.
Everything is SI: positions and displacements in m, rotations in rad, forces in
N, moments in N m.

Layout of every case file
-------------------------
- Points: the particle centres, in the caller's order (point k = particle k).
- Cell block 0, ``line``: the bonds, in the caller's order (cell k = bond k,
  connectivity ``bonds[k] = (i, j)``). Omitted when there are no bonds.
- Cell block 1, ``vertex``: one cell per particle (cell M + k = particle k), so
  that particles render in ParaView's Surface representation even where no
  bond touches them.
- Point data: ``displacement`` (N,3) m, ``rotation`` (N,3) rad (axial vectors),
  ``radius`` (N,) m, plus the case's extra point arrays.
- Cell data: ``axial_force`` (N, positive in tension), ``shear_force`` (N),
  ``moment`` (N m), ``is_bond`` (int8: 1 on bond lines, 0 on particle
  vertices), plus the case's extra cell arrays. VTU needs every cell array on
  every cell, so the bond arrays are 0.0 on the vertex cells (no NaN: the files
  stay finite, like everything amfe writes). Colour ranges therefore include
  0; ``Threshold`` on ``is_bond`` (or ParaView's "Extract Cells By Type")
  shows the bonds alone.

The collection
--------------
``cases.pvd`` lists the case files by relative path with ``timestep`` = case
index (0..5 for the six Voigt cases xx, yy, zz, yz, xz, xy) and a ``name``
attribute; in ParaView the time slider steps through the load cases.

Atomicity
---------
All inputs are validated before anything is touched; a validation error leaves
the directory as it was. Then an existing ``cases.pvd`` is removed first, every
case is written to a hidden temporary file in the same directory, the
temporaries are ``os.replace``-d onto their final names, and ``cases.pvd`` is
written last (also via a temporary and ``os.replace``). So ``cases.pvd`` is
present if and only if the last write completed: a crash leaves either a
complete, consistent set or no ``.pvd`` (and no temporaries, unless the process
is killed outright). Old case files of a previous write are overwritten; old
``case_<k>_<name>.vtu`` files that are not part of the new set are removed
after the new set is complete, so the directory holds one consistent set.
"""
import os
import re
import secrets
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from xml.sax.saxutils import quoteattr

import numpy as np

from amfe.model.bonds import validate_particles
from amfe.io.atomic import fsync_dir
from amfe.errors import AmfeError, _list_items

from amfe.vocab import CASE_NAMES as VOIGT_NAMES
PVD_NAME = "cases.pvd"

_POINT_REQUIRED = ("displacement", "rotation")
_CELL_REQUIRED = ("axial_force", "shear_force", "moment")
_POINT_RESERVED = _POINT_REQUIRED + ("radius",)
_CELL_RESERVED = _CELL_REQUIRED + ("is_bond",)
_CASE_KEYS = set(_POINT_REQUIRED) | set(_CELL_REQUIRED) | {"point_data", "cell_data"}
_SAFE_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")
_CASE_FILE = re.compile(r"^case_\d+_[A-Za-z0-9_\-]+\.vtu$")


def case_filename(k, name):
    """File name of load case `k` (0-based) called `name`: ``case_<k>_<name>.vtu``."""
    return f"case_{k}_{name}.vtu"


def write_load_cases(directory, centers, radii, bonds, cases, names=None):
    """Write one VTU file per load case and a ``cases.pvd`` collection.

    Parameters
    ----------
    directory : str or path-like
        Output directory; created (with parents) if missing.
    centers : array_like (N, 3) float, m
        Particle centres (the VTU points).
    radii : array_like (N,) float, m
        Particle radii (point data ``radius``); finite and positive.
    bonds : array_like (M, 2) int
        Particle indices (i, j) of each bond, 0 <= i, j < N, i != j (the VTU
        ``line`` cells). M may be 0: shape (0, 2).
    cases : sequence of mappings, one per load case (normally six, Voigt order
        xx, yy, zz, yz, xz, xy), each with
        - ``"displacement"`` (N, 3) float, m;
        - ``"rotation"`` (N, 3) float, rad;
        - ``"axial_force"`` (M,) float, N, positive in tension;
        - ``"shear_force"`` (M,) float, N;
        - ``"moment"`` (M,) float, N m;
        - optionally ``"point_data"``: {name: (N,) or (N, k) array} and
          ``"cell_data"``: {name: (M,) or (M, k) array} of extra arrays (extra
          cell arrays are 0 on the particle vertex cells). Names must be
          distinct from the built-in ones. Other keys are an error.
        Float arrays are written as float64 (exactly, no rounding); integer
        arrays keep their type, booleans become uint8. Every value must be
        finite.
    names : sequence of str, optional
        One name per case (letters, digits, ``_``, ``-``; distinct). Defaults
        to ``VOIGT_NAMES`` when there are six cases; required otherwise.

    Returns
    -------
    list of str
        Paths of the case files in case order, then the path of ``cases.pvd``.

    Raises
    ------
    AmfeError
        Mismatched shapes, non-finite values, bad bond indices or names (before
        any file is touched), or a failure while writing (the directory then
        holds no ``cases.pvd`` and no temporaries).
    """
    import meshio

    centers, radii = validate_particles(centers, radii)
    n = centers.shape[0]
    bonds = _validate_bonds(bonds, n)
    m = bonds.shape[0]
    cases, names = _validate_cases(cases, names, n, m)

    directory = os.fspath(directory)
    try:
        os.makedirs(directory, exist_ok=True)
    except OSError as exc:
        raise AmfeError(f"cannot create the output directory {directory!r}: {exc}") from exc

    pvd_path = os.path.join(directory, PVD_NAME)
    final = [os.path.join(directory, case_filename(k, nm)) for k, nm in enumerate(names)]
    temps = []
    try:
        # 1. No stale collection can outlive a failed write.
        if os.path.lexists(pvd_path):
            os.remove(pvd_path)
        # 2. Every case to a temporary file beside its final name.
        for k, (case, nm) in enumerate(zip(cases, names)):
            mesh = _build_mesh(meshio, centers, radii, bonds, case)
            tmp = _make_temp(directory, case_filename(k, nm))
            temps.append(tmp)
            meshio.write(tmp, mesh, file_format="vtu", binary=True, compression="zlib")
            _fsync_file(tmp)
        # 3. Into place.
        for tmp, path in zip(temps, final):
            os.replace(tmp, path)
        temps = []
        # 4. The collection, last.
        tmp = _make_temp(directory, PVD_NAME)
        temps.append(tmp)
        with open(tmp, "x", encoding="utf-8") as f:
            f.write(_pvd_text([os.path.basename(p) for p in final], names))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, pvd_path)
        temps = []
        fsync_dir(directory)
    except BaseException as exc:
        for tmp in temps:
            try:
                os.remove(tmp)
            except OSError:
                pass
        if isinstance(exc, Exception) and not isinstance(exc, AmfeError):
            raise AmfeError(f"writing the load-case files in {directory!r} failed "
                            f"({type(exc).__name__}: {exc}); no {PVD_NAME} was left, "
                            f"so no partial set looks complete") from exc
        raise

    # 5. Case files of an earlier, different set would be orphans: remove them.
    keep = {os.path.basename(p) for p in final}
    for entry in os.listdir(directory):
        if _CASE_FILE.match(entry) and entry not in keep:
            try:
                os.remove(os.path.join(directory, entry))
            except OSError:
                pass
    return final + [pvd_path]


def read_case(path):
    """Read one case file written by :func:`write_load_cases`.

    Returns a dict with ``points`` (N,3) m, ``bonds`` (M,2) int, ``radius``
    (N,) m, ``displacement`` (N,3) m, ``rotation`` (N,3) rad, ``axial_force``
    (M,) N, ``shear_force`` (M,) N, ``moment`` (M,) N m, and ``point_data`` /
    ``cell_data`` dicts holding every point array and the bond-line part of
    every cell array (vertex cells dropped).
    """
    import meshio

    try:
        mesh = meshio.read(os.fspath(path), file_format="vtu")
    except Exception as exc:
        raise AmfeError(f"cannot read the case file {os.fspath(path)!r}: {exc}") from exc
    line_blocks = [k for k, c in enumerate(mesh.cells) if c.type == "line"]
    if len(line_blocks) > 1:
        raise AmfeError(f"{os.fspath(path)!r} has {len(line_blocks)} line blocks; "
                        "not a file written by amfe")
    if line_blocks:
        kb = line_blocks[0]
        bonds = np.asarray(mesh.cells[kb].data)
        cell_data = {name: np.asarray(arrs[kb]) for name, arrs in mesh.cell_data.items()}
    else:
        bonds = np.zeros((0, 2), dtype=np.int64)
        cell_data = {name: np.asarray(arrs[0])[:0] for name, arrs in mesh.cell_data.items()}
    point_data = {name: np.asarray(a) for name, a in mesh.point_data.items()}
    out = {"points": np.asarray(mesh.points), "bonds": bonds,
           "point_data": point_data, "cell_data": cell_data}
    for name in _POINT_RESERVED:
        if name in point_data:
            out[name] = point_data[name]
    for name in _CELL_REQUIRED:
        if name in cell_data:
            out[name] = cell_data[name]
    return out


def read_collection(path):
    """Parse a ``.pvd`` collection: list of (timestep float, name str, absolute path)."""
    path = os.fspath(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise AmfeError(f"cannot read the collection {path!r}: {exc}") from exc
    base = os.path.dirname(os.path.abspath(path))
    return [(float(ds.get("timestep", "nan")), ds.get("name", ""),
             os.path.join(base, ds.get("file")))
            for ds in root.iter("DataSet")]


# --------------------------------------------------------------------------- helpers


def _validate_bonds(bonds, n):
    arr = np.asarray(bonds)
    if arr.ndim == 1 and arr.size == 0:  # [] means no bonds
        arr = arr.reshape(0, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise AmfeError(f"bonds must have shape (M, 2), got {arr.shape}")
    if arr.size and arr.dtype.kind not in "iu":
        if arr.dtype.kind != "f" or not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise AmfeError(f"bonds must hold integer particle indices, got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    bad = np.flatnonzero(((arr < 0) | (arr >= n)).any(axis=1))
    if bad.size:
        raise AmfeError(f"{bad.size} bonds refer to particles outside 0..{n - 1}: bonds "
                        + _list_items(f"{k} {tuple(arr[k])}" for k in bad))
    bad = np.flatnonzero(arr[:, 0] == arr[:, 1])
    if bad.size:
        raise AmfeError(f"{bad.size} bonds join a particle to itself: bonds "
                        + _list_items(f"{k} {tuple(arr[k])}" for k in bad))
    return arr


def _as_array(value, what):
    try:
        arr = np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise AmfeError(f"{what} is not a numeric array: {exc}") from exc
    if arr.dtype.kind == "b":
        return arr.astype(np.uint8)
    if arr.dtype.kind in "iu":
        return arr
    if arr.dtype.kind == "c":
        raise AmfeError(f"{what} is complex; amfe writes real values only")
    try:
        arr = arr.astype(np.float64)
    except (TypeError, ValueError) as exc:
        raise AmfeError(f"{what} is not a numeric array (dtype {arr.dtype})") from exc
    bad = np.flatnonzero(~np.isfinite(arr).all(axis=tuple(range(1, arr.ndim))))
    if bad.size:
        raise AmfeError(f"{what} has non-finite values ({bad.size} rows: {_list_items(bad)})")
    return arr


def _check_shape(arr, expected, what, unit):
    if arr.shape != expected:
        raise AmfeError(f"{what} must have shape {expected} [{unit}], got {arr.shape}")


def _extra(case, key, rows, reserved, what):
    extra = case.get(key, {}) or {}
    if not isinstance(extra, Mapping):
        raise AmfeError(f"{what}['{key}'] must be a dict of name -> array")
    out = {}
    for name, value in extra.items():
        if not isinstance(name, str) or not name or name in reserved:
            raise AmfeError(f"{what}['{key}'] has a bad array name {name!r} "
                            f"(must be a non-empty string other than {', '.join(reserved)})")
        arr = _as_array(value, f"{what}['{key}']['{name}']")
        if arr.ndim not in (1, 2) or arr.shape[0] != rows:
            raise AmfeError(f"{what}['{key}']['{name}'] must have shape ({rows},) or "
                            f"({rows}, k), got {arr.shape}")
        out[name] = arr
    return out


def _validate_cases(cases, names, n, m):
    if isinstance(cases, Mapping) or not hasattr(cases, "__len__"):
        raise AmfeError("cases must be a list of dicts, one per load case")
    cases = list(cases)
    if not cases:
        raise AmfeError("cases is empty: nothing to write")
    if names is None:
        if len(cases) != len(VOIGT_NAMES):
            raise AmfeError(f"{len(cases)} load cases given: pass names=[...] (the default "
                            f"names {list(VOIGT_NAMES)} are for six cases)")
        names = list(VOIGT_NAMES)
    else:
        if isinstance(names, str):
            raise AmfeError("names must be a list of strings, not one string")
        names = list(names)
    if len(names) != len(cases):
        raise AmfeError(f"{len(names)} names for {len(cases)} load cases")
    for nm in names:
        if not isinstance(nm, str) or not _SAFE_NAME.match(nm):
            raise AmfeError(f"case name {nm!r} must use only letters, digits, '_' and '-'")
    if len(set(names)) != len(names):
        raise AmfeError(f"case names must be distinct, got {names}")

    out = []
    for k, case in enumerate(cases):
        what = f"load case {k} ({names[k]})"
        if not isinstance(case, Mapping):
            raise AmfeError(f"{what} must be a dict, got {type(case).__name__}")
        missing = [key for key in _POINT_REQUIRED + _CELL_REQUIRED if key not in case]
        if missing:
            raise AmfeError(f"{what} lacks {', '.join(missing)}")
        unknown = sorted(str(key) for key in case if key not in _CASE_KEYS)
        if unknown:
            raise AmfeError(f"{what} has unknown keys {', '.join(unknown)}; put extra arrays "
                            "in case['point_data'] / case['cell_data']")
        c = {}
        for key, unit in (("displacement", "m"), ("rotation", "rad")):
            arr = _as_array(case[key], f"{what} {key}").astype(np.float64)
            _check_shape(arr, (n, 3), f"{what} {key}", unit)
            c[key] = arr
        for key, unit in (("axial_force", "N"), ("shear_force", "N"), ("moment", "N m")):
            arr = _as_array(case[key], f"{what} {key}").astype(np.float64)
            _check_shape(arr, (m,), f"{what} {key}", unit)
            c[key] = arr
        c["point_data"] = _extra(case, "point_data", n, _POINT_RESERVED, what)
        c["cell_data"] = _extra(case, "cell_data", m, _CELL_RESERVED, what)
        out.append(c)
    return out, names


def _build_mesh(meshio, centers, radii, bonds, case):
    n, m = centers.shape[0], bonds.shape[0]
    cells = []
    if m:
        cells.append(("line", bonds))
    cells.append(("vertex", np.arange(n, dtype=np.int64).reshape(n, 1)))

    def blocks(line_values):
        line_values = np.ascontiguousarray(line_values)
        pad = np.zeros((n,) + line_values.shape[1:], dtype=line_values.dtype)
        return [line_values, pad] if m else [pad]

    point_data = {"displacement": case["displacement"], "rotation": case["rotation"],
                  "radius": radii}
    point_data.update(case["point_data"])
    cell_data = {key: blocks(case[key]) for key in _CELL_REQUIRED}
    cell_data["is_bond"] = blocks(np.ones(m, dtype=np.int8))
    for name, arr in case["cell_data"].items():
        cell_data[name] = blocks(arr)
    return meshio.Mesh(centers, cells, point_data=point_data, cell_data=cell_data)


def _make_temp(directory, final_name):
    """A fresh hidden name beside `final_name` (not created: the writer creates it, so
    the file gets the usual umask permissions, unlike mkstemp's 0600)."""
    while True:
        tmp = os.path.join(directory, f".{final_name}.{os.getpid()}.{secrets.token_hex(6)}.tmp")
        if not os.path.lexists(tmp):
            return tmp


def _fsync_file(path):
    with open(path, "rb+") as f:
        os.fsync(f.fileno())


def _pvd_text(files, names):
    lines = ['<?xml version="1.0"?>',
             "<!-- amfe load cases: timestep k = load case k (Voigt order xx, yy, zz, yz, xz, "
             "xy for six cases); SI units: m, rad, N, N m -->",
             '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
             "  <Collection>"]
    for k, (f, nm) in enumerate(zip(files, names)):
        lines.append(f'    <DataSet timestep="{k}" group="" part="0" file={quoteattr(f)} '
                     f'name={quoteattr(nm)}/>')
    lines += ["  </Collection>", "</VTKFile>", ""]
    return "\n".join(lines)
