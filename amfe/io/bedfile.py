"""Bed files (HDF5, docs/model.md, section 6).

Layout:

    /particles/centers   (N,3) float64, particle centres [m]
    /particles/radii     (N,)  float64, particle radii [m]
    root group attributes: the bed's attrs (material and generation parameters)

The attributes live on the root group, so that ``h5dump -A`` or
``h5py.File(p).attrs`` shows them first; the datasets carry ``units = 'm'``.
:func:`read_bed` accepts any HDF5 file with the two datasets (other tools hand
beds in this way): attributes are optional, integer and float32 data are
converted to float64.
"""
import math
import os

import h5py
import numpy as np

from amfe.errors import AmfeError
from amfe.io.atomic import atomic_write
from amfe.model.bed import Bed
from amfe.model.bonds import check_shapes
from amfe.model.material import check_material_names
from amfe.model.memory import READ_BYTES, check_memory
from amfe.model.torus import check_box

CENTERS = "particles/centers"
RADII = "particles/radii"


def _attr_value(key, value):
    """An attrs value as h5py should store it; AmfeError for what HDF5 attributes cannot hold."""
    if isinstance(value, (str, bool, np.bool_)):
        return value
    if isinstance(value, (int, float, np.integer, np.floating)):
        return value
    if isinstance(value, (list, tuple, np.ndarray)):
        arr = np.asarray(value)
        if arr.dtype.kind in "biuf":
            return arr
    raise AmfeError(f"bed attribute {key!r} must be a str, bool, int, float or a numeric array, "
                    f"got {type(value).__name__}: {value!r}")


def _from_attr(value):
    """An HDF5 attribute as a plain Python value: scalars -> int/float/bool/str, arrays -> lists."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "OSU":
            return [v.decode("utf-8") if isinstance(v, bytes) else str(v) for v in value.ravel()]
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_bed(path: str | os.PathLike, bed: Bed) -> None:
    """Write ``bed`` to the HDF5 file ``path`` (overwriting it), atomically.

    The file is written under a temporary name in the same directory and
    renamed into place with os.replace, so a reader never sees a half-written
    bed and a crash leaves any previous file intact; the temporary file is
    removed on any error. Attribute values must be str, bool, int, float or
    numeric lists/arrays (AmfeError otherwise, before anything is written).
    """
    path = os.fspath(path)
    if not isinstance(bed, Bed):
        raise AmfeError(f"write_bed needs an amfe.model.bed.Bed, got {type(bed).__name__}")
    attrs = {str(k): _attr_value(k, v) for k, v in bed.attrs.items()}
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise AmfeError(f"cannot write {path}: directory {directory} does not exist")

    def write(tmp):
        with h5py.File(tmp, "w") as f:
            grp = f.create_group("particles")
            c = grp.create_dataset("centers", data=np.ascontiguousarray(bed.centers, np.float64))
            r = grp.create_dataset("radii", data=np.ascontiguousarray(bed.radii, np.float64))
            c.attrs["units"] = "m"
            r.attrs["units"] = "m"
            for k, v in attrs.items():
                f.attrs[k] = v

    try:
        atomic_write(path, write, by_name=True)
    except OSError as exc:
        raise AmfeError(f"cannot write {path}: {exc.strerror or exc}") from None


def _name(h5name):
    """An HDF5 object name as text (a damaged file can hold names that are not UTF-8)."""
    return h5name.decode("utf-8", "replace") if isinstance(h5name, bytes) else h5name


# What h5py raises for a damaged file or a dangling link, beyond OSError: RuntimeError
# ("Unable to get link info"), KeyError (an external link to a missing file, an object header
# past the end), ValueError (a damaged type, an attribute that is not UTF-8).
DAMAGED = (OSError, RuntimeError, KeyError, ValueError)


def _dataset(f, name, path):
    """The h5py dataset /name of a bed file, checked to hold real numbers (not read yet)."""
    if name not in f:
        have = []
        f.visit(have.append)
        raise AmfeError(f"{path} is not a bed file: it has no /{name} dataset "
                        f"(it holds: {', '.join('/' + _name(h) for h in have) or 'nothing'}). "
                        f"A bed needs /{CENTERS} (N,3) and /{RADII} (N,) in m")
    obj = f[name]
    if not isinstance(obj, h5py.Dataset):
        raise AmfeError(f"{path}: /{name} must be a dataset, found a {type(obj).__name__}")
    if obj.dtype.kind not in "iuf":
        raise AmfeError(f"{path}: /{name} must hold real numbers (float64), got dtype {obj.dtype}")
    return obj


# The attributes amfe's generator writes, by the type they must have where present
# (attributes of other names pass through unchecked).
REAL_ATTRS = ("material_E", "material_nu", "material_psi", "material_density", "mean_radius",
              "r0", "jitter", "layer_thickness", "a_star_max", "a_star_critical",
              "scan_track_width", "scan_hatch_spacing", "scan_angle", "scan_layer_rotation",
              "scan_skip_fraction", "scan_skip_length", "scan_offset")
COUNT_ATTRS = ("seed", "n_lattice", "n_scanned_out", "n_shrunk", "shrink_passes")
VECTOR_ATTRS = {"size": 3, "enlargement": 2}
TEXT_ATTRS = ("generator", "amfe_version", "units", "scan")


def check_attrs(attrs, path="the bed"):
    """AmfeError naming the first of amfe's bed attributes that has the wrong type.

    Reals must be finite real numbers, counts (seed, n_*) integers in
    [0, 2**64), size three positive lengths [m], enlargement two factors,
    and generator, amfe_version, units, scan text; and no attribute may look
    like the material without being spelt as amfe reads it
    (:func:`amfe.model.material.check_material_names`: material_e, E).
    """
    def bad(key, want):
        value = attrs[key]
        raise AmfeError(f"{path}: bed attribute {key} must be {want}, got "
                        f"{type(value).__name__} {value!r}; fix or delete the attribute")

    def real(v):
        return (isinstance(v, (int, float)) and not isinstance(v, bool)
                and math.isfinite(v))

    for key in REAL_ATTRS:
        if key in attrs and not real(attrs[key]):
            bad(key, "a finite real number")
    for key in COUNT_ATTRS:
        v = attrs.get(key, 0)
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < 2**64:
            bad(key, "an integer in [0, 2**64)")
    for key, n in VECTOR_ATTRS.items():
        v = attrs.get(key, [1.0] * n)
        if not (isinstance(v, list) and len(v) == n and all(real(x) and x > 0 for x in v)):
            bad(key, f"{n} positive finite numbers")
    for key in TEXT_ATTRS:
        if key in attrs and not isinstance(attrs[key], str):
            bad(key, "text")
    check_material_names(attrs, path)


def read_bed(path: str | os.PathLike, max_memory: float | str | None = None) -> Bed:
    """Read a bed from any HDF5 file with /particles/centers (N,3) and /particles/radii (N,) [m].

    Root attributes become ``Bed.attrs`` (plain Python values; arrays as
    lists); those amfe's generator writes must have their types
    (:func:`check_attrs`). Raises AmfeError, saying what is wrong, for a
    missing file, a file that is not HDF5, missing or non-numeric datasets,
    wrong shapes, non-finite values and non-positive radii, attributes of
    the wrong type, and a file whose arrays would take more than
    ``max_memory`` bytes (default: half the machine's memory) to read,
    checked from the shapes before anything is read.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise AmfeError(f"bed file {path} does not exist")
    if os.path.isdir(path):
        raise AmfeError(f"bed file {path} is a directory")
    try:
        is_h5 = h5py.is_hdf5(path)
    except OSError as exc:
        raise AmfeError(f"cannot read bed file {path}: {exc}") from None
    if not is_h5:
        raise AmfeError(f"{path} is not an HDF5 file (a bed file holds /{CENTERS} and /{RADII})")
    try:
        with h5py.File(path, "r") as f:
            c, r = _dataset(f, CENTERS, path), _dataset(f, RADII, path)
            try:
                check_shapes(c.shape, r.shape)
            except AmfeError as exc:
                raise AmfeError(f"{path}: {exc}") from None
            n = c.shape[0]
            check_memory(READ_BYTES * n, max_memory, f"reading {path} ({n} particles)")
            attrs = {k: _from_attr(v) for k, v in f.attrs.items()}
            check_attrs(attrs, path)
            centers = np.asarray(c[()], dtype=np.float64)
            radii = np.asarray(r[()], dtype=np.float64)
    except OSError as exc:
        raise AmfeError(f"cannot read bed file {path}: {exc}") from None
    except DAMAGED as exc:   # (an AmfeError is none of these: it passes as it is)
        why = str(exc).strip("'\"") or type(exc).__name__   # KeyError's text comes quoted
        raise AmfeError(f"cannot read bed file {path}: it is damaged or links to a file that "
                        f"is missing ({why})") from None
    try:
        bed = Bed(centers=centers, radii=radii, attrs=attrs)  # checks the arrays
        if "periodic" in attrs:  # a periodic bed (docs/model.md, section 9)
            check_box(attrs["periodic"], bed.radii)
    except AmfeError as exc:
        raise AmfeError(f"{path}: {exc}") from None
    return bed
