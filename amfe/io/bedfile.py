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
import os

import h5py
import numpy as np

from amfe.model.bed import Bed
from amfe.model.bonds import validate_particles
from amfe.model.torus import check_box
from amfe.io.atomic import atomic_write
from amfe.errors import AmfeError

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


def write_bed(path, bed: Bed):
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


def _read_array(f, name, path):
    if name not in f:
        have = []
        f.visit(have.append)
        raise AmfeError(f"{path} is not a bed file: it has no /{name} dataset "
                        f"(it holds: {', '.join('/' + h for h in have) or 'nothing'}). "
                        f"A bed needs /{CENTERS} (N,3) and /{RADII} (N,) in m")
    obj = f[name]
    if not isinstance(obj, h5py.Dataset):
        raise AmfeError(f"{path}: /{name} must be a dataset, found a {type(obj).__name__}")
    if obj.dtype.kind not in "iuf":
        raise AmfeError(f"{path}: /{name} must hold real numbers (float64), got dtype {obj.dtype}")
    return np.asarray(obj[()], dtype=np.float64)


def read_bed(path) -> Bed:
    """Read a bed from any HDF5 file with /particles/centers (N,3) and /particles/radii (N,) [m].

    Root attributes become ``Bed.attrs`` (plain Python values; arrays as
    lists). Raises AmfeError, saying what is wrong, for a missing file, a file
    that is not HDF5, missing or non-numeric datasets, wrong shapes, non-finite
    values and non-positive radii.
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
            centers = _read_array(f, CENTERS, path)
            radii = _read_array(f, RADII, path)
            attrs = {k: _from_attr(v) for k, v in f.attrs.items()}
    except OSError as exc:
        raise AmfeError(f"cannot read bed file {path}: {exc}") from None
    try:
        centers, radii = validate_particles(centers, radii)
        if "periodic" in attrs:  # a periodic bed (docs/model.md, section 9)
            check_box(attrs["periodic"], radii)
    except AmfeError as exc:
        raise AmfeError(f"{path}: {exc}") from None
    return Bed(centers=centers, radii=radii, attrs=attrs)
