"""Merging a labelling run's parts into its data-set file, written kill-safe and checked
(docs/model.md, section 6). Split from amfe.dataset.datafile, which lays out and reads the
files, and amfe.dataset.datacheck, which checks them."""
import datetime
import os

import numpy as np

from amfe.dataset.datacheck import check_dataset
from amfe.dataset.datafile import DENSITY_DEFINITION, SECONDS_NAMES, _image_dataset
from amfe.dataset.images import IMAGING_VERSION
from amfe.dataset.parts import (
    LABEL_RULE_VERSION,
    done_indices,
    part_path,
    part_problem,
    read_part,
    reject_part,
    remove_parts,
)
from amfe.errors import AmfeError, _list_items
from amfe.io.atomic import atomic_write_h5
from amfe.model.material import STEEL
from amfe.model.scales import PARAM_NAMES, PARAM_UNITS, get_scale
from amfe.vocab import LABEL_NAMES


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


#: Records copied from a finished file at a time (bounded memory for large data sets).
_BLOCK = 256


def _copy_base(rows, bonds, pdata, base, n):
    """Copy rows 0..n-1 of the finished data-set file ``base`` into ``rows``, ``bonds`` and
    ``pdata`` unchanged; returns whether it has bond images (files made before them lack
    them, and so does the merged file)."""
    import h5py

    steel = {"E": STEEL.E, "nu": STEEL.nu, "psi": STEEL.psi}   # files before these columns
    with h5py.File(base, "r") as src:
        has_bonds = "bond_images" in src and src["bond_images"].shape[1:] == bonds.shape[1:]
        pairs = [(ds, src[name]) for name, ds in rows.items()]
        pairs += [(bonds, src["bond_images"])] if has_bonds else []
        for a in range(0, n, _BLOCK):
            b = min(n, a + _BLOCK)
            for ds, s in pairs:
                ds[a:b] = s.asstr()[a:b] if s.dtype.kind == "O" else s[a:b]
        for j, name in enumerate(PARAM_NAMES):
            pdata[:n, j] = src["params"][name][:n] if name in src["params"] else steel[name]
    return has_bonds


def _copy_parts(rows, bonds, output, parts, params, pdata, start=0):
    """Copy part k into row k of ``rows`` for start <= k < len(rows['index']), each checked
    first, and its generation parameters into ``pdata[k]``.

    Returns whether every part had a bond image. A part that is not its
    record is moved aside and the merge refused (:func:`merge_parts`).
    """
    count, shape = rows["index"].shape[0], bonds.shape[1:]
    all_bonds = True
    for k in range(start, count):
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
    return all_bonds


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

def merge_parts(output, parts, params, first=None, base=None):
    """Merge the records 0..count-1 of ``parts`` into the HDF5 file ``output``: (data, attrs).

    ``first``: merge only records 0..first-1, into a data set of ``first``
    records, and keep the parts (a prefix of a running data set: what
    ``amfe dataset --count first`` with the same seed would make; attribute
    prefix_of names the source). ``params`` stay those of the run that wrote
    the parts, against which every part is checked. ``base``: (path, n):
    records 0..n-1 are the rows of the finished data-set file ``path`` of
    the same run (checked by :func:`amfe.dataset.plan.prepare`), copied
    unchanged; the parts hold the rest (a finished data set grown by a
    larger count, or a prefix of one).

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
    source, base = (None, 0) if base is None else (os.fspath(base[0]), min(int(base[1]), count))
    missing = sorted(set(range(base, count)) - set(done_indices(parts, count)))
    if missing:
        raise AmfeError(f"cannot merge {output}: {len(missing)} record(s) missing in {parts} "
                        f"({_list_items(missing)}); run the same command again")
    shape = sc.image_shape

    def write(f):
        rows = _create_rows(f, count, shape)
        bonds = _image_dataset(f, "bond_images", count, shape)
        pdata = np.empty((count, len(PARAM_NAMES)))
        all_bonds = _copy_base(rows, bonds, pdata, source, base) if base else True
        all_bonds &= _copy_parts(rows, bonds, output, parts, params, pdata, start=base)
        if not all_bonds:   # parts written before bond images existed have none
            del f["bond_images"]
        pg = f.create_group("params")
        for j, name in enumerate(PARAM_NAMES):
            ds = pg.create_dataset(name, data=pdata[:, j])
            ds.attrs["units"] = PARAM_UNITS[name]
        f.attrs.update({k: v for k, v in params.items()})
        if first is not None:
            whole = source if count <= base else parts
            f.attrs.update({"count": count, "prefix_of": f"{whole} (count {params['count']})"})
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
