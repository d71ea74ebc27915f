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
import datetime
import os

import numpy as np

from amfe.dataset.images import IMAGING_VERSION
from amfe.dataset.parts import (
    LABEL_RULE_VERSION,
    STATUS_FAILED,
    STATUS_OK,
    done_indices,
    part_path,
    part_problem,
    read_part,
    reject_part,
    remove_parts,
)
from amfe.errors import AmfeError, _list_items
from amfe.io.atomic import atomic_write_h5
from amfe.io.h5damage import damaged, read_every_chunk
from amfe.model.boxscale import draw_material
from amfe.model.material import STEEL
from amfe.model.scales import PARAM_NAMES, PARAM_UNITS, get_scale, record_seed
from amfe.vocab import LABEL_NAMES

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


def _create_rows(f, count, shape):
    """The per-record datasets of the layout (all but bond_images and params), by name."""
    import h5py

    d = {
        "images": _image_dataset(f, "images", count, shape),
        "labels": f.create_dataset("labels", (count, 6), np.float64),
        "C": f.create_dataset("C", (count, 6, 6), np.float64),
        "density": f.create_dataset("density", (count,), np.float64),
        "index": f.create_dataset("index", (count,), np.int64),
        "seed": f.create_dataset("seed", (count,), np.int64),
        "status": f.create_dataset("status", (count,), np.uint8),
        "reason": f.create_dataset("reason", (count,), h5py.string_dtype()),
        "iterations": f.create_dataset("iterations", (count, 6), np.int32),
        "n_particles": f.create_dataset("n_particles", (count,), np.int64),
        "n_removed": f.create_dataset("n_removed", (count,), np.int64),
        "n_bonds": f.create_dataset("n_bonds", (count,), np.int64),
        "volume": f.create_dataset("volume", (count,), np.float64),
        "seconds": f.create_dataset("seconds", (count, 3), np.float64),
        "solver": f.create_dataset("solver", (count,), h5py.string_dtype()),
    }
    d["labels"].attrs["columns"] = list(LABEL_NAMES)
    d["labels"].attrs["units"] = "Pa for Ex, Ey, Ez; - for the Poisson ratios"
    d["C"].attrs["units"] = "Pa"
    d["seconds"].attrs["columns"] = list(SECONDS_NAMES)
    return d


def _copy_parts(rows, bonds, output, parts, params):
    """Copy part k into row k of ``rows`` for k < len(rows['index']), each checked first.

    Returns (every part had a bond image, params (count, len(PARAM_NAMES))).
    A part that is not its record is moved aside and the merge refused
    (:func:`merge_parts`).
    """
    count, shape = rows["index"].shape[0], bonds.shape[1:]
    all_bonds, pdata = True, np.empty((count, len(PARAM_NAMES)))
    for k in range(count):
        path = part_path(parts, k)
        try:
            rec = read_part(path)
            why = part_problem(path, k, params, rec)
        except AmfeError as exc:
            why = str(exc)
        if why is not None:
            dest = reject_part(path, output)
            raise AmfeError(f"record file {path} was refused ({why}) and moved to "
                            f"{dest}; run the same command again to recompute it")
        for name, ds in rows.items():
            ds[k] = rec["image" if name == "images" else name]
        if "bond_image" in rec and rec["bond_image"].shape == shape:
            bonds[k] = rec["bond_image"]
        else:
            all_bonds = False
        pdata[k] = _padded(rec["params"])
    return all_bonds, pdata


def _padded(params):
    """A part's params row in :data:`PARAM_NAMES`' order: parts written before the material
    columns (E, nu, psi) existed were steel's, and get steel's values."""
    params = np.asarray(params, np.float64)
    tail = [STEEL.E, STEEL.nu, STEEL.psi][params.shape[0] - len(PARAM_NAMES):] \
        if params.shape[0] < len(PARAM_NAMES) else []
    return np.concatenate([params, tail])


def _layout_attrs(sc):
    """The root attributes that describe the layout and the images of scale ``sc``."""
    return {
        "label_names": list(LABEL_NAMES),
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "bed_size": list(sc.size), "layer_thickness": sc.layer_thickness,
        "image_cell": [sc.cell[0], sc.cell[1], sc.layer_thickness],
        "image_shape": list(sc.image_shape), "image_box": list(sc.image_box),
        "material_spec": _material_spec(sc),
        "image_spacing": sc.image_spacing,
        "density_definition": DENSITY_DEFINITION,
        "status_codes": "0 ok, 1 failed (see reason)",
        "label_rule_version": LABEL_RULE_VERSION, "imaging_version": IMAGING_VERSION,
    }


def _material_spec(sc):
    """The scale's particle material, in words (the values of each record: params/E, nu, psi)."""
    if sc.material == "draw":
        return (f"drawn per bed: nu ~ U({sc.nu_range[0]:g}, {sc.nu_range[1]:g}), psi ~ "
                f"U({sc.psi_range[0]:g}, {sc.psi_range[1]:g}), E steel's 210 GPa")
    return f"{sc.material} for every bed (amfe.model.material)"


# ---------------------------------------------------------------- merge

def merge_parts(output, parts, params, first=None):
    """Merge the records 0..count-1 of ``parts`` into the HDF5 file ``output``: (data, attrs).

    ``first``: merge only records 0..first-1, into a data set of ``first``
    records, and keep the parts (a prefix of a running data set: what
    ``amfe dataset --count first`` with the same seed would make; attribute
    prefix_of names the source). ``params`` stay those of the run that wrote
    the parts, against which every part is checked.

    Order, so that nothing good is lost: the file is written under a
    temporary name, checked (:func:`check_dataset`), renamed onto ``output``,
    and only then is ``parts`` removed. A kill or a failure before the rename
    leaves the parts intact and ``output`` as it was. A part that is not the
    record it claims to be (:func:`amfe.dataset.parts.part_problem`: another
    data set's, damaged) is moved to ``OUTPUT.rejected/`` and the merge is
    refused with an AmfeError naming it: a rerun recomputes that record. Also
    AmfeError for missing records and for a full disk.
    """
    count = int(params["count"]) if first is None else int(first)
    sc = get_scale(params["scale"])
    missing = sorted(set(range(count)) - set(done_indices(parts, count)))
    if missing:
        raise AmfeError(f"cannot merge {output}: {len(missing)} record(s) missing in {parts} "
                        f"({_list_items(missing)}); run the same command again")
    shape = sc.image_shape

    def write(f):
        rows = _create_rows(f, count, shape)
        bonds = _image_dataset(f, "bond_images", count, shape)
        all_bonds, pdata = _copy_parts(rows, bonds, output, parts, params)
        if not all_bonds:   # parts written before bond images existed have none
            del f["bond_images"]
        pg = f.create_group("params")
        for j, name in enumerate(PARAM_NAMES):
            ds = pg.create_dataset(name, data=pdata[:, j])
            ds.attrs["units"] = PARAM_UNITS[name]
        f.attrs.update({k: v for k, v in params.items()})
        if first is not None:
            f.attrs.update({"count": count, "prefix_of": f"{parts} (count {params['count']})"})
        f.attrs.update(_layout_attrs(sc))

    checked = {}

    def check(tmp):
        problems, data, attrs = check_dataset(tmp)
        if problems:
            raise AmfeError(f"the merged file fails its check ({'; '.join(problems)}); {output} "
                            f"is left as it was and the records are kept in {parts}")
        checked.update(data=data, attrs=attrs)

    atomic_write_h5(output, write, check=check)
    if first is None:
        remove_parts(parts)
    return checked["data"], checked["attrs"]


# ---------------------------------------------------------------- check and summary

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


def check_dataset(path):
    """Validate a data-set file: returns (problems: list of str, data, attrs).

    Checks: the datasets of the layout exist with consistent shapes (one row
    per record, M = attrs count, images of the scale's shape); index is
    exactly 0..M-1 (duplicates and missing indices named); seed matches
    record_seed(attrs seed, index); status is 0 or 1; ok rows have finite
    labels, C and density, positive moduli; failed rows have a reason; image
    values are finite and in [0, 1].
    """
    import h5py

    with damaged(path, "data set", DATA_SET_FIX):
        data, attrs = load_dataset(path)
        with h5py.File(path, "r") as f:   # every chunk, also of datasets load_dataset skips
            read_every_chunk(f)
    problems = _layout_problems(data, attrs)
    if problems:
        return problems, data, attrs
    return _record_problems(data, attrs), data, attrs


def _layout_problems(data, attrs):
    """Problems of the layout: required datasets, their dtypes, row counts and shapes."""
    problems = []
    for name, (tail, kinds) in REQUIRED.items():
        if name not in data:
            problems.append(f"missing dataset /{name}")
        elif data[name].dtype.kind not in kinds:
            problems.append(f"/{name} has dtype {data[name].dtype}")
    if problems:
        return problems
    M = data["index"].shape[0]
    count = attrs.get("count")
    if count is None:
        problems.append("no 'count' attribute")
    elif int(count) != M:
        problems.append(f"{M} rows but the count attribute says {int(count)}")
    for name, (tail, _) in REQUIRED.items():
        arr = data[name]
        if arr.shape[:1] != (M,):
            problems.append(f"/{name} has {arr.shape[0] if arr.ndim else 0} rows, /index {M}")
        elif tail is not None and arr.shape[1:] != tail:
            problems.append(f"/{name} rows have shape {arr.shape[1:]}, expected {tail}")
    img = data["images"]
    try:
        expect = get_scale(attrs.get("scale")).image_shape
    except AmfeError as exc:
        problems.append(str(exc))
        expect = None
    if img.ndim != 4:
        problems.append(f"/images must be (M, layers, H, W), got shape {img.shape}")
    elif expect is not None and img.shape[1:] != tuple(expect):
        problems.append(f"/images rows have shape {img.shape[1:]}, scale {attrs.get('scale')} "
                        f"makes {tuple(expect)}")
    if expect is not None and "bed_size" in attrs and not np.array_equal(
            np.asarray(attrs["bed_size"], np.float64), np.asarray(get_scale(attrs["scale"]).size)):
        problems.append(f"the bed_size attribute {list(attrs['bed_size'])} is not scale "
                        f"{attrs.get('scale')}'s box")
    return problems


def _material_problems(data, attrs):
    """Records whose material (params/E, nu, psi) is not one the scale's spec can draw."""
    p = data.get("params", {})
    if not all(n in p for n in ("E", "nu", "psi")):
        return []   # files made before the material columns: steel
    sc = get_scale(attrs.get("scale"))
    E, nu, psi = (np.asarray(p[n], np.float64) for n in ("E", "nu", "psi"))
    if sc.material == "draw":
        ok = ((E == draw_material(sc, 0).E) & (nu >= sc.nu_range[0]) & (nu <= sc.nu_range[1])
              & (psi >= sc.psi_range[0]) & (psi <= sc.psi_range[1]))
    else:
        m = draw_material(sc, 0)
        ok = (E == m.E) & (nu == m.nu) & (psi == m.psi)
    ok |= np.isnan(E) & (data["status"] != STATUS_OK)   # a bed that failed before its draw
    bad = np.flatnonzero(~ok)
    if not bad.size:
        return []
    return [f"records {_list_items(np.ravel(data['index'][bad]), 8)} have a material (params/E, "
            f"nu, psi) that scale {attrs.get('scale')} does not make"]


def _record_problems(data, attrs):
    """Problems of the records of a file whose layout is right (see :func:`check_dataset`)."""
    problems = []
    M, img = data["index"].shape[0], data["images"]
    index = data["index"].astype(np.int64)
    uniq, counts = np.unique(index, return_counts=True)
    dup = uniq[counts > 1]
    if dup.size:
        problems.append(f"duplicate record indices: {_list_items(np.ravel(dup), 8)}")
    missing = np.setdiff1d(np.arange(M), index)
    if missing.size:
        problems.append(f"missing record indices: {_list_items(np.ravel(missing), 8)}")
    if not dup.size and not missing.size and np.any(index != np.arange(M)):
        problems.append("rows are not sorted by record index")
    if "seed" in attrs and not dup.size:
        want = np.array([record_seed(int(attrs["seed"]), int(k)) for k in index if k >= 0])
        have = data["seed"].astype(np.int64)[index >= 0]
        bad = np.flatnonzero(want != have)
        if bad.size:
            problems.append(f"bed seeds do not match record_seed(data set seed, index) for "
                            f"records {_list_items(np.ravel(index[index >= 0][bad]), 8)}")
    status = data["status"].astype(np.int64)
    bad = np.flatnonzero((status != STATUS_OK) & (status != STATUS_FAILED))
    if bad.size:
        problems.append(f"unknown status values at rows {_list_items(np.ravel(bad), 8)}")
    ok = status == STATUS_OK
    lab, C, dens = data["labels"], data["C"], data["density"]
    bad = np.flatnonzero(ok & ~(np.all(np.isfinite(lab), 1) & np.all(np.isfinite(C), (1, 2))
                                & np.isfinite(dens)))
    if bad.size:
        problems.append("ok records with non-finite labels, C or density: "
                        f"{_list_items(np.ravel(index[bad]), 8)}")
    bad = np.flatnonzero(ok & np.isfinite(lab).all(1) & np.any(lab[:, :3] <= 0, axis=1))
    if bad.size:
        problems.append("ok records with non-positive moduli: "
                        f"{_list_items(np.ravel(index[bad]), 8)}")
    reasons = data["reason"]
    bad = np.flatnonzero((status == STATUS_FAILED) & (np.char.str_len(reasons.astype(str)) == 0))
    if bad.size:
        problems.append(f"failed records without a reason: {_list_items(np.ravel(index[bad]), 8)}")
    if not np.all(np.isfinite(img)) or img.min(initial=0) < -1e-6 or img.max(initial=0) > 1 + 1e-6:
        problems.append("image values outside [0, 1] or not finite")
    fin = np.isfinite(dens)
    if np.any((dens[fin] < 0) | (dens[fin] > 1)):
        problems.append("packing densities outside [0, 1]")
    problems += _material_problems(data, attrs)
    if "bond_images" in data:
        b = data["bond_images"]
        if b.shape != img.shape:
            problems.append(f"/bond_images has shape {b.shape}, /images {img.shape}")
        elif not np.all(np.isfinite(b)) or b.min(initial=0) < 0:
            problems.append("bond image values negative or not finite")
    return problems


