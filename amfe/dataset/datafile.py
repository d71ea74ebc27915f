"""Data-set files (docs/model.md, section 6): a record per bed, written kill-safe, merged, checked.

While ``amfe dataset -o DATA.h5`` runs, every finished record (or failure) is
its own small file ``DATA.h5.parts/rec_KKKKKKKK.npz``, written under a
temporary name, fsync'ed and renamed into place (os.replace), so a part file
is either complete or absent whatever moment the job is killed.
``DATA.h5.parts/params.json`` holds the parameters that define the records
(scale, seed, count, rtol, amfe version): a rerun with other parameters is
refused. When every record exists, :func:`merge_parts` writes DATA.h5 through
a temporary file, checks it, renames it into place (os.replace) and only then
removes the parts directory.

DATA.h5 layout, one row per record, rows sorted by record index 0..M-1:

    images      (M, layers, H, W) float32  volume fraction per cell (docs/model.md, section 7)
    bond_images (M, layers, H, W) float32  bond-stiffness image (amfe.dataset.bondimage), same grid;
                absent in files made before it existed: add it with
                ``amfe dataset --add-bond-images DATA.h5`` (:func:`add_bond_images`)
    labels      (M, 6) float64  Ex, Ey, Ez [Pa], nu_yz, nu_xz, nu_xy [-]
    C           (M, 6, 6) float64  stiffness [Pa], Voigt xx, yy, zz, yz, xz, xy
    density     (M,) float64  packing density = mean of the image
    index       (M,) int64    the record number k
    seed        (M,) int64    the bed's own seed, record_seed(dataset seed, k)
    status      (M,) uint8    0 ok, 1 failed
    reason      (M,) str      why a record failed ("" when ok)
    iterations  (M, 6) int32  CG iterations per load case (-1 if not solved)
    n_particles (M,) int64    particles of the generated bed (-1 if none)
    n_removed   (M,) int64    of them not load-carrying (-1 if not solved)
    n_bonds     (M,) int64    bonds of the load-carrying frame (-1 if not solved)
    volume      (M,) float64  homogenization volume [m^3]: format 2 the bed's box, format 1
                              the hull of the kept centres
    seconds     (M, 3) float64  generate, image, homogenize wall times [s]
    solver      (M,) str      JSON of homogenize_bed's solver record ("" if not solved)
    params/NAME (M,) float64  the bed's generation parameters (amfe.model.scales.PARAM_NAMES)

Failed rows have NaN labels, C and volume; their image and density are those
of the generated bed when generation succeeded, zeros and NaN otherwise.
Root attributes: format, format_version, scale, seed, count, rtol,
amfe_version, label_names, created (UTC, ISO 8601), bed_size [m],
layer_thickness [m], image_cell [m], image_shape, image_spacing [m] (the
sample spacing given to amfe.dataset.images.pixelate), density_definition,
status_codes, label_rule_version, imaging_version (files made before
these existed lack them: version 1). A record's image is
``pixelate(bed, cell, layer_thickness, box=((0, 0, 0), bed_size),
spacing=image_spacing)`` of the bed ``amfe pack --scale SCALE --seed SEED``
regenerates; its bond image is ``bond_image`` of that bed on the same grid.
"""
import os

import numpy as np

from amfe.dataset.parts import (
    done_indices,
)
from amfe.errors import AmfeError

SECONDS_NAMES = ("generate", "image", "homogenize")
DENSITY_DEFINITION = ("mean of the image: the volume fraction of the box [0,Lx]x[0,Ly]x[0,Lz] "
                      "filled by the union of the spheres")
BOND_IMAGE_DEFINITION = ("sum over the bonds whose midpoint lies in the cell of k_n L^2 / "
                         "(E V_cell), dimensionless (amfe.dataset.bondimage)")


# ---------------------------------------------------------------- parts


def _image_dataset(f, name, count, shape, data=None):
    """An (count, *shape) float32 image dataset, one gzip'ed chunk per record."""
    ds = f.create_dataset(name, (count, *shape), np.float32, data=data, chunks=(1, *shape),
                          compression="gzip", compression_opts=1, shuffle=True)
    ds.attrs["axes"] = "record, layer (z), y, x"
    if name == "bond_images":
        ds.attrs["definition"] = BOND_IMAGE_DEFINITION
    return ds


IMAGE_DATASETS = ("images", "bond_images")
REQUIRED = {  # name: (trailing shape or None for the image's, dtype kinds)
    "images": (None, "f"), "labels": ((6,), "f"), "C": ((6, 6), "f"), "density": ((), "f"),
    "index": ((), "iu"), "seed": ((), "iu"), "status": ((), "iu"), "reason": ((), "OSU"),
}


#: What to do with a data set HDF5 cannot read (:func:`amfe.io.h5damage.damaged`).
DATA_SET_FIX = ("restore it from a copy, or make it again with amfe dataset (its label tables "
                "rebuild it without solving: amfe dataset --from-labels)")


def missing_dataset(path):
    """Why data set ``path`` (no such file) is missing: "does not exist", or, where a run's
    parts directory is there, that the run has not finished (its records are kept there)."""
    parts = path + ".parts"
    if not os.path.isdir(parts):
        return f"data set {path} does not exist"
    done = len(done_indices(parts, 10**12))
    return (f"data set {path} is not finished: its run has {done} record(s) in {parts} and "
            "writes the file when every record is done; let that run finish, or run the same "
            "amfe dataset command again to resume it, then use the file")


def load_dataset(path, images=True):
    """All arrays of a data-set file as a dict (params as a nested dict), and its attrs."""
    import h5py
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise AmfeError(missing_dataset(path))
    if not h5py.is_hdf5(path):
        raise AmfeError(f"{path} is not an HDF5 file")
    with h5py.File(path, "r") as f:
        data = {}
        for name, obj in f.items():
            if isinstance(obj, h5py.Dataset) and (images or name not in IMAGE_DATASETS):
                data[name] = obj.asstr()[()] if obj.dtype.kind == "O" else obj[()]
        data["params"] = {n: f["params"][n][()] for n in f["params"]} if "params" in f else {}
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
    return data, attrs
