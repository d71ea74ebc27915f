"""Checking a data-set file (``amfe dataset --check``): its layout, its records and their
materials, every chunk read (docs/model.md, section 6). Split from amfe.dataset.datafile,
which writes and reads the files."""
import numpy as np

from amfe.dataset.datafile import DATA_SET_FIX, REQUIRED, load_dataset
from amfe.dataset.parts import STATUS_FAILED, STATUS_OK
from amfe.errors import AmfeError, _list_items
from amfe.io.h5damage import damaged, read_every_chunk
from amfe.model.boxscale import draw_material
from amfe.model.scales import get_scale, record_seed


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


