"""Data-set files (DESIGN section 6): one record per bed, written kill-safe, merged, checked.

While ``amfe dataset -o DATA.h5`` runs, every finished record (or failure) is
its own small file ``DATA.h5.parts/rec_KKKKKKKK.npz``, written under a
temporary name, fsync'ed and renamed into place (os.replace), so a part file
is either complete or absent whatever moment the job is killed.
``DATA.h5.parts/params.json`` holds the parameters that define the records
(scale, seed, count, rtol, amfe version): a rerun with other parameters is
refused. When every record exists, :func:`merge_parts` writes DATA.h5 (again
through a temporary file and os.replace) and removes the parts directory.

DATA.h5 layout, one row per record, rows sorted by record index 0..M-1:

    images      (M, layers, H, W) float32  volume fraction per cell (DESIGN 7)
    bond_images (M, layers, H, W) float32  bond-stiffness image (amfe.bondimage), same grid;
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
    volume      (M,) float64  homogenization volume [m^3] (hull of the kept centres)
    seconds     (M, 3) float64  generate, image, homogenize wall times [s]
    solver      (M,) str      JSON of homogenize_bed's solver record ("" if not solved)
    params/NAME (M,) float64  the bed's generation parameters (amfe.scales.PARAM_NAMES)

Failed rows have NaN labels, C and volume; their image and density are those
of the generated bed when generation succeeded, zeros and NaN otherwise.
Root attributes: format, format_version, scale, seed, count, rtol,
amfe_version, label_names, created (UTC, ISO 8601), bed_size [m],
layer_thickness [m], image_cell [m], image_shape, image_spacing [m] (the
sample spacing given to amfe.images.pixelate), density_definition,
status_codes. A record's image is
``pixelate(bed, cell, layer_thickness, box=((0, 0, 0), bed_size),
spacing=image_spacing)`` of the bed ``amfe pack --scale SCALE --seed SEED``
regenerates; its bond image is ``bond_image`` of that bed on the same grid.
"""
import datetime
import json
import os
import re
import shutil

import numpy as np

from . import __version__
from .atomicio import atomic_write
from .errors import AmfeError
from .scales import PARAM_NAMES, PARAM_UNITS, get_scale, record_seed

FORMAT = "amfe.dataset"
FORMAT_VERSION = 1
LABEL_NAMES = ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy")
SECONDS_NAMES = ("generate", "image", "homogenize")
STATUS_OK, STATUS_FAILED = 0, 1
DENSITY_DEFINITION = ("mean of the image: the volume fraction of the box [0,Lx]x[0,Ly]x[0,Lz] "
                      "filled by the union of the spheres")
PARAMS_JSON = "params.json"
BOND_IMAGE_DEFINITION = ("sum over the bonds whose midpoint lies in the cell of k_n L^2 / "
                         "(E V_cell), dimensionless (amfe.bondimage)")
_PART = re.compile(r"^rec_(\d{8})\.npz$")


def parts_dir(output):
    """The parts directory of data-set file ``output``: ``OUTPUT.parts``."""
    return os.fspath(output) + ".parts"


def part_path(parts, k):
    return os.path.join(parts, f"rec_{k:08d}.npz")


def run_params(scale, seed, count, rtol):
    """The parameters that define a data set's records (what params.json and the attrs hold)."""
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "scale": str(scale),
            "seed": int(seed), "count": int(count), "rtol": float(rtol),
            "amfe_version": __version__}


def remove_stale_tmp(directory, prefix):
    """Remove temporary files ``.PREFIX*.tmp`` left in ``directory`` by a killed run."""
    removed = 0
    try:
        names = os.listdir(directory)
    except FileNotFoundError:
        return 0
    for name in names:
        if name.startswith("." + prefix) and name.endswith(".tmp"):
            try:
                os.remove(os.path.join(directory, name))
                removed += 1
            except FileNotFoundError:
                pass
    return removed


# ---------------------------------------------------------------- parts

def record_bond_image(bed, sc):
    """The bond image of a record's bed on its scale's grid (box [0, scale size])."""
    from .bondimage import bond_image
    return bond_image(bed, cell=sc.cell, layer_thickness=sc.layer_thickness,
                      box=((0.0, 0.0, 0.0), sc.size))


def _image_dataset(f, name, count, shape, data=None):
    """An (count, *shape) float32 image dataset, one gzip'ed chunk per record."""
    ds = f.create_dataset(name, (count, *shape), np.float32, data=data, chunks=(1, *shape),
                          compression="gzip", compression_opts=1, shuffle=True)
    ds.attrs["axes"] = "record, layer (z), y, x"
    if name == "bond_images":
        ds.attrs["definition"] = BOND_IMAGE_DEFINITION
    return ds


def empty_record(k, bed_seed, image_shape):
    """A record with nothing computed yet (NaN labels, zero image), status failed."""
    return {
        "index": int(k), "seed": int(bed_seed), "status": STATUS_FAILED, "reason": "",
        "image": np.zeros(image_shape, np.float32),
        "bond_image": np.zeros(image_shape, np.float32),
        "labels": np.full(6, np.nan), "C": np.full((6, 6), np.nan), "density": np.nan,
        "iterations": np.full(6, -1, np.int32), "n_particles": -1, "n_removed": -1,
        "n_bonds": -1, "volume": np.nan, "seconds": np.zeros(3), "solver": "",
        "params": np.full(len(PARAM_NAMES), np.nan),
    }


def write_part(parts, rec):
    """Write one record as ``parts/rec_KKKKKKKK.npz``, atomically (tmp, fsync, os.replace)."""
    arrays = {
        "index": np.int64(rec["index"]), "seed": np.int64(rec["seed"]),
        "status": np.uint8(rec["status"]), "reason": np.str_(rec["reason"]),
        "image": np.asarray(rec["image"], np.float32),
        "bond_image": np.asarray(rec["bond_image"], np.float32),
        "labels": np.asarray(rec["labels"], np.float64).reshape(6),
        "C": np.asarray(rec["C"], np.float64).reshape(6, 6),
        "density": np.float64(rec["density"]),
        "iterations": np.asarray(rec["iterations"], np.int32).reshape(6),
        "n_particles": np.int64(rec["n_particles"]), "n_removed": np.int64(rec["n_removed"]),
        "n_bonds": np.int64(rec["n_bonds"]), "volume": np.float64(rec["volume"]),
        "seconds": np.asarray(rec["seconds"], np.float64).reshape(3),
        "solver": np.str_(rec["solver"]),
        "params": np.asarray(rec["params"], np.float64).reshape(len(PARAM_NAMES)),
    }
    path = part_path(parts, rec["index"])
    atomic_write(path, lambda fh: np.savez(fh, **arrays))
    return path


def read_part(path):
    """One part file as a record dict (AmfeError if it cannot be read)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            rec = {k: z[k] for k in z.files}
    except Exception as exc:  # noqa: BLE001 - any damage is reported the same way
        raise AmfeError(f"cannot read record file {path}: {exc}") from None
    for key in ("index", "seed", "status", "n_particles", "n_removed", "n_bonds"):
        rec[key] = int(rec[key])
    for key in ("density", "volume"):
        rec[key] = float(rec[key])
    rec["reason"], rec["solver"] = str(rec["reason"]), str(rec["solver"])
    return rec


def done_indices(parts, count):
    """Sorted record indices < count whose part file exists."""
    try:
        names = os.listdir(parts)
    except FileNotFoundError:
        return []
    out = []
    for name in names:
        m = _PART.match(name)
        if m and int(m.group(1)) < count:
            out.append(int(m.group(1)))
    return sorted(out)


def read_params_json(parts):
    path = os.path.join(parts, PARAMS_JSON)
    try:
        with open(path) as fh:
            return json.load(fh)
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise AmfeError(f"cannot read {path}: {exc}; remove the directory {parts} to start "
                        "afresh") from None


def write_params_json(parts, params):
    data = json.dumps(params, indent=2).encode() + b"\n"
    atomic_write(os.path.join(parts, PARAMS_JSON), lambda fh: fh.write(data))


def describe_params(p):
    return (f"scale {p.get('scale')}, seed {p.get('seed')}, count {p.get('count')}, "
            f"rtol {p.get('rtol')}, amfe {p.get('amfe_version')}")


# ---------------------------------------------------------------- merge

def merge_parts(output, parts, params):
    """Write every record 0..count-1 of ``parts`` into the HDF5 file ``output``; remove ``parts``.

    The file is written under a temporary name and renamed into place, so a
    kill during the merge leaves the parts intact and no ``output``; a rerun
    redoes the merge. Raises AmfeError naming missing or unreadable records
    (an unreadable part is removed, so that a rerun recomputes it).
    """
    import h5py

    count = int(params["count"])
    sc = get_scale(params["scale"])
    missing = sorted(set(range(count)) - set(done_indices(parts, count)))
    if missing:
        from .errors import _list_items
        raise AmfeError(f"cannot merge {output}: {len(missing)} record(s) missing in {parts} "
                        f"({_list_items(missing)}); run the same command again")
    shape = sc.image_shape

    def write(tmp):
        with h5py.File(tmp, "w") as f:
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
            bonds = _image_dataset(f, "bond_images", count, shape)
            all_bonds = True   # parts written before bond images existed have none
            pg = f.create_group("params")
            pdata = np.empty((count, len(PARAM_NAMES)))
            for k in range(count):
                path = part_path(parts, k)
                try:
                    rec = read_part(path)
                except AmfeError:
                    os.remove(path)
                    raise AmfeError(f"record file {path} was damaged and has been removed; run "
                                    "the same command again to recompute it") from None
                if rec["index"] != k or rec["image"].shape != shape:
                    os.remove(path)
                    raise AmfeError(f"record file {path} does not hold record {k} of shape "
                                    f"{shape} (index {rec['index']}, image "
                                    f"{rec['image'].shape}); it has been removed, run the same "
                                    "command again")
                for name, ds in d.items():
                    ds[k] = rec["image" if name == "images" else name]
                if "bond_image" in rec and rec["bond_image"].shape == shape:
                    bonds[k] = rec["bond_image"]
                else:
                    all_bonds = False
                pdata[k] = rec["params"]
            if not all_bonds:
                del f["bond_images"]
            for j, name in enumerate(PARAM_NAMES):
                ds = pg.create_dataset(name, data=pdata[:, j])
                ds.attrs["units"] = PARAM_UNITS[name]
            d["labels"].attrs["columns"] = list(LABEL_NAMES)
            d["labels"].attrs["units"] = "Pa for Ex, Ey, Ez; - for the Poisson ratios"
            d["C"].attrs["units"] = "Pa"
            d["seconds"].attrs["columns"] = list(SECONDS_NAMES)
            f.attrs.update({k: v for k, v in params.items()})
            f.attrs.update({
                "label_names": list(LABEL_NAMES),
                "created": datetime.datetime.now(datetime.timezone.utc).isoformat(
                    timespec="seconds"),
                "bed_size": list(sc.size), "layer_thickness": sc.layer_thickness,
                "image_cell": [sc.cell[0], sc.cell[1], sc.layer_thickness],
                "image_shape": list(shape),
                "image_spacing": sc.image_spacing,
                "density_definition": DENSITY_DEFINITION,
                "status_codes": "0 ok, 1 failed (see reason)",
            })

    atomic_write(output, write, by_name=True)
    shutil.rmtree(parts, ignore_errors=True)


# ---------------------------------------------------------------- check and summary

IMAGE_DATASETS = ("images", "bond_images")
REQUIRED = {  # name: (trailing shape or None for the image's, dtype kinds)
    "images": (None, "f"), "labels": ((6,), "f"), "C": ((6, 6), "f"), "density": ((), "f"),
    "index": ((), "iu"), "seed": ((), "iu"), "status": ((), "iu"), "reason": ((), "OSU"),
}


def load_dataset(path, images=True):
    """All arrays of a data-set file as a dict (params as a nested dict), and its attrs."""
    import h5py
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise AmfeError(f"data set {path} does not exist")
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
    try:
        data, attrs = load_dataset(path)
    except OSError as exc:
        raise AmfeError(f"cannot read {path}: {exc}") from None
    problems = []
    for name, (tail, kinds) in REQUIRED.items():
        if name not in data:
            problems.append(f"missing dataset /{name}")
        elif data[name].dtype.kind not in kinds:
            problems.append(f"/{name} has dtype {data[name].dtype}")
    if problems:
        return problems, data, attrs
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
    if problems:
        return problems, data, attrs

    index = data["index"].astype(np.int64)
    uniq, counts = np.unique(index, return_counts=True)
    dup = uniq[counts > 1]
    if dup.size:
        problems.append(f"duplicate record indices: {_few(dup)}")
    missing = np.setdiff1d(np.arange(M), index)
    if missing.size:
        problems.append(f"missing record indices: {_few(missing)}")
    if not dup.size and not missing.size and np.any(index != np.arange(M)):
        problems.append("rows are not sorted by record index")
    if "seed" in attrs and not dup.size:
        want = np.array([record_seed(int(attrs["seed"]), int(k)) for k in index if k >= 0])
        have = data["seed"].astype(np.int64)[index >= 0]
        bad = np.flatnonzero(want != have)
        if bad.size:
            problems.append(f"bed seeds do not match record_seed(data set seed, index) for "
                            f"records {_few(index[index >= 0][bad])}")
    status = data["status"].astype(np.int64)
    bad = np.flatnonzero((status != STATUS_OK) & (status != STATUS_FAILED))
    if bad.size:
        problems.append(f"unknown status values at rows {_few(bad)}")
    ok = status == STATUS_OK
    lab, C, dens = data["labels"], data["C"], data["density"]
    bad = np.flatnonzero(ok & ~(np.all(np.isfinite(lab), 1) & np.all(np.isfinite(C), (1, 2))
                                & np.isfinite(dens)))
    if bad.size:
        problems.append(f"ok records with non-finite labels, C or density: {_few(index[bad])}")
    bad = np.flatnonzero(ok & np.isfinite(lab).all(1) & np.any(lab[:, :3] <= 0, axis=1))
    if bad.size:
        problems.append(f"ok records with non-positive moduli: {_few(index[bad])}")
    reasons = data["reason"]
    bad = np.flatnonzero((status == STATUS_FAILED) & (np.char.str_len(reasons.astype(str)) == 0))
    if bad.size:
        problems.append(f"failed records without a reason: {_few(index[bad])}")
    if not np.all(np.isfinite(img)) or img.min(initial=0) < -1e-6 or img.max(initial=0) > 1 + 1e-6:
        problems.append("image values outside [0, 1] or not finite")
    fin = np.isfinite(dens)
    if np.any((dens[fin] < 0) | (dens[fin] > 1)):
        problems.append("packing densities outside [0, 1]")
    if "bond_images" in data:
        b = data["bond_images"]
        if b.shape != img.shape:
            problems.append(f"/bond_images has shape {b.shape}, /images {img.shape}")
        elif not np.all(np.isfinite(b)) or b.min(initial=0) < 0:
            problems.append("bond image values negative or not finite")
    return problems, data, attrs


def add_bond_images(path, progress=True):
    """Add ``/bond_images`` to a data-set file made before it existed; returns the record count.

    Each record's bed is regenerated from its seed (``bed_for(scale, seed)``,
    what ``amfe pack --scale S --seed SEED`` does) and imaged by
    :func:`amfe.bondimage.bond_image` on the file's grid; records whose bed
    cannot be made get zeros (they are failed records). The file is rewritten
    through a temporary copy and os.replace, so a kill leaves it as it was.
    About 0.05 s per `small` bed. AmfeError if the file already has bond
    images, is not a valid data set, or a bed no longer matches its image
    (generator changed since the file was made).
    """
    import h5py

    from .scales import bed_for

    path = os.fspath(path)
    problems, data, attrs = check_dataset(path)
    if problems:
        raise AmfeError(f"{path} is not a valid data set ({problems[0]}); see amfe dataset "
                        "--check")
    if "bond_images" in data:
        raise AmfeError(f"{path} already has /bond_images")
    sc = get_scale(attrs["scale"])
    M = data["index"].shape[0]
    out = np.zeros((M, *sc.image_shape), np.float32)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=M, desc="bond images", unit="bed", dynamic_ncols=True)
    for k in range(M):
        try:
            bed = bed_for(sc, int(data["seed"][k]))
        except AmfeError:
            bed = None
        if bed is not None:
            if bed.n != int(data["n_particles"][k]) and int(data["n_particles"][k]) >= 0:
                raise AmfeError(f"record {k} of {path}: its seed now makes a bed of {bed.n} "
                                f"particles, the file says {int(data['n_particles'][k])}; the "
                                "generator has changed since the file was made: remake it")
            try:
                out[k] = record_bond_image(bed, sc)
            except AmfeError:
                if int(data["status"][k]) == STATUS_OK:
                    raise
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()

    def write(tmp):
        shutil.copyfile(path, tmp)
        with h5py.File(tmp, "r+") as f:
            _image_dataset(f, "bond_images", M, sc.image_shape, data=out)

    atomic_write(path, write, by_name=True)
    return M


def _few(values, limit=8):
    values = [int(v) for v in np.asarray(values).ravel()]
    head = ", ".join(map(str, values[:limit]))
    return head + (f", ... ({len(values) - limit} more)" if len(values) > limit else "")


def reason_key(reason):
    """A failure reason with its numbers blanked, for grouping similar failures."""
    return re.sub(r"[-+]?\d+(\.\d+)?([eE][-+]?\d+)?", "#", str(reason)).strip()[:120]


def failure_groups(status, reasons):
    """[(count, reason key)] of the failed records, most frequent first."""
    groups = {}
    for s, r in zip(status, reasons):
        if int(s) != STATUS_OK:
            key = reason_key(r)
            groups[key] = groups.get(key, 0) + 1
    return sorted(((n, k) for k, n in groups.items()), key=lambda t: (-t[0], t[1]))


def density_histogram(density, bins=10, width=40):
    """Text histogram of the finite packing densities (one line per bin)."""
    d = np.asarray(density, float)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return "packing density: no values"
    lo, hi = float(d.min()), float(d.max())
    if hi - lo < 1e-9:
        return f"packing density: all {d.size} records at {lo:.3f}"
    counts, edges = np.histogram(d, bins=bins, range=(lo, hi))
    peak = counts.max()
    lines = [f"packing density (mean of the image), {d.size} records, "
             f"min {lo:.3f} median {np.median(d):.3f} max {hi:.3f}:"]
    for c, a, b in zip(counts, edges[:-1], edges[1:]):
        bar = "#" * int(round(width * c / peak)) if peak else ""
        lines.append(f"  {a:.3f}-{b:.3f} {c:6d} {bar}")
    return "\n".join(lines)


def summary_text(data, attrs):
    """A few lines: records, ok/failed with grouped reasons, label ranges, density histogram."""
    status = data["status"]
    M = status.shape[0]
    ok = status == STATUS_OK
    lines = [f"{M} records (scale {attrs.get('scale')}, seed {attrs.get('seed')}, amfe "
             f"{attrs.get('amfe_version')}, created {attrs.get('created')}): {int(ok.sum())} ok, "
             f"{int(M - ok.sum())} failed; images {'x'.join(map(str, data['images'].shape[1:]))}"]
    for n, key in failure_groups(status, data["reason"]):
        lines.append(f"  failed {n:5d} x {key}")
    if ok.any():
        lab = data["labels"][ok]
        for j, name in enumerate(LABEL_NAMES):
            scale, unit = (1e9, " GPa") if j < 3 else (1.0, "")
            v = lab[:, j] / scale
            lines.append(f"  {name:6s} min {v.min():9.4g}  median {np.median(v):9.4g}  "
                         f"max {v.max():9.4g}{unit}")
    lines.append(density_histogram(data["density"][ok] if ok.any() else data["density"]))
    return "\n".join(lines)
