"""A data set's part files: one ``rec_NNNNNNNN.npz`` per finished record, and params.json.

``amfe dataset`` writes each record as soon as it is solved (atomically), so a
killed run loses only the beds in flight; :mod:`amfe.dataset.datafile` merges
the parts into the HDF5 file (docs/datasets.md).
"""
import io
import json
import os
import re
import shutil

import numpy as np

from amfe.errors import AmfeError
from amfe.io.atomic import atomic_write
from amfe.model.continuum_springs import springs_record
from amfe.model.scales import PARAM_NAMES, get_scale, record_seed
from amfe.version import __version__

FORMAT = "amfe.dataset"
#: 2: labels under label rule 2 (issue 30: the pieces the condition loads, V the bed's box);
#: files of version 1 stay readable and are named as made under rule 1.
FORMAT_VERSION = 2
#: The label rule of each format version (docs/model.md, section 5; docs/datasets.md).
LABEL_RULES = {
    1: "label rule 1: the largest bonded component, V = hull of its centres",
    2: "label rule 2: the pieces the condition loads, V = the bed's box",
}


def label_rule(attrs):
    """The label rule (1 or 2) of a data set from its root attributes (format_version)."""
    version = int((attrs or {}).get("format_version", 1))
    return 1 if version < 2 else 2


#: The version of the rule that turns a bed into its labels (which particles carry load,
#: the homogenization volume, the boundary conditions' averages): the rule of
#: FORMAT_VERSION. Bump it when a label changes for the same bed; label tables
#: (amfe.dataset.labels) record it, and a table of another rule is refused by
#: `amfe dataset --from-labels`.
LABEL_RULE_VERSION = label_rule({"format_version": FORMAT_VERSION})
STATUS_OK, STATUS_FAILED = 0, 1
PARAMS_JSON = "params.json"
REJECTED_SUFFIX = ".rejected"
_PART = re.compile(r"^rec_(\d{8})\.npz$")


def parts_dir(output):
    """The parts directory of data-set file ``output``: ``OUTPUT.parts``."""
    return os.fspath(output) + ".parts"



def rejected_dir(output):
    """Where refused part files of data-set file ``output`` are kept: ``OUTPUT.rejected``."""
    return os.fspath(output) + REJECTED_SUFFIX


def part_path(parts, k):
    return os.path.join(parts, f"rec_{k:08d}.npz")



def run_params(scale, seed, count, rtol, solver="gamg", bc="kubc", springs="paper"):
    """The parameters that define a data set's records (what params.json and the attrs hold).

    ``solver`` (the --solver asked for), ``bc`` and ``springs`` are recorded unless they
    are "gamg", "kubc" and "paper", so the parameters of runs made before these choices
    existed stay equal; continuum springs are recorded with their fitted values
    (:func:`amfe.model.continuum_springs.springs_record`), so a run is resumed only
    with the same ones.
    """
    params = {"format": FORMAT, "format_version": FORMAT_VERSION, "scale": str(scale),
              "seed": int(seed), "count": int(count), "rtol": float(rtol),
              "amfe_version": __version__}
    if solver != "gamg":
        params["solver"] = str(solver)
    if bc != "kubc":
        params["bc"] = str(bc)
    if springs != "paper":
        # JSON text: an HDF5 attribute holds no dict
        params["springs"] = json.dumps(springs_record(springs), sort_keys=True)
    return params



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



def write_part(parts, rec, run=None):
    """Write one record as ``parts/rec_KKKKKKKK.npz``, atomically (tmp, fsync, os.replace).

    run: the run parameters (:func:`run_params`), stored in the part as JSON
    so that a part of another data set is recognised (:func:`part_problem`).
    """
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
    if run is not None:
        arrays["run"] = np.str_(json.dumps(run, sort_keys=True))
    path = part_path(parts, rec["index"])
    buf = io.BytesIO()   # zipped in memory: a full disk cannot leave a half-closed zip behind
    np.savez(buf, **arrays)
    atomic_write(path, lambda fh: fh.write(buf.getbuffer()), clean=False)  # swept at start-up
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
    if "run" in rec:
        rec["run"] = json.loads(str(rec["run"]))
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



#: The root attributes of a data-set file that are its run parameters (:func:`run_params`,
#: and those of a run from label tables); :func:`file_params` reads them back.
RUN_KEYS = ("format", "format_version", "scale", "seed", "count", "rtol", "amfe_version",
            "solver", "bc", "springs", "from_labels", "solved_from")


def _plain(value):
    """An HDF5 attribute as the JSON value params.json would hold (numpy scalars, bytes)."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value.item() if isinstance(value, np.generic) else value


def file_params(attrs, extra=()):
    """The run parameters of a finished data-set file, from its root attributes ``attrs``:
    the :data:`RUN_KEYS` (and ``extra``) it has, as :func:`run_params` makes them."""
    return {k: _plain(attrs[k]) for k in (*RUN_KEYS, *extra) if k in attrs}


def _count_like(a, b):
    """The parameters that may differ between two runs of the same records (see below)."""
    skip = {"count"}
    if "from_labels" in a and "from_labels" in b:
        skip |= {"from_labels", "solved_from"}
    return skip


def param_differences(a, b):
    """What differs between run parameters ``a`` (a file's or a run's) and ``b`` (asked),
    beside what :func:`same_but_count` allows, in words: ["seed 5 (asked 6)", ...]."""
    skip, default = _count_like(a, b), {"solver": "gamg", "bc": "kubc"}   # run_params omits
    return [f"{n} {a.get(n, default.get(n, '(none)'))} (asked {b.get(n, default.get(n, '(none)'))})"
            for n in sorted((set(a) | set(b)) - skip) if a.get(n) != b.get(n)]


def same_but_count(a, b):
    """Whether run parameters ``a`` and ``b`` differ at most in the run's length.

    Record k is a function of (seed, k) and the method alone, so a record of
    a run of N records is record k of the same run grown to M > N records.
    Two runs from label tables (``from_labels``) may also differ in the
    tables and where solving starts (``solved_from``): a record rebuilt from
    a table equals the one solved (tests/test_labels.py), so a run continued
    with ``--solve-rest`` keeps its parts when a shard exported meanwhile
    joins its tables.
    """
    skip = _count_like(a, b)
    return {n: v for n, v in a.items() if n not in skip} == \
        {n: v for n, v in b.items() if n not in skip}


def part_problem(path, k, params, rec=None):
    """Why part file ``path`` is not record ``k`` of the run ``params`` (None if it is).

    Checks, reading only the small members unless ``rec`` (the part, read)
    is given: it can be read; its index is k; its bed seed is
    record_seed(params seed, k); its stored run parameters (parts written
    before they were stored have none) equal ``params`` but for the count
    (:func:`same_but_count`: a grown run keeps its parts); its images have
    the scale's shape.
    """
    want_seed = record_seed(int(params["seed"]), k)
    try:
        if rec is None:
            with np.load(path, allow_pickle=False) as z:   # the image only for old parts
                names = ("index", "seed", "run") if "run" in z.files else ("index", "seed", "image")
                rec = {n: z[n] for n in names}
        index, seed = int(rec["index"]), int(rec["seed"])
        run = rec.get("run")
        run = json.loads(str(run)) if isinstance(run, (str, np.ndarray)) else run
        shape = tuple(np.shape(rec["image"])) if "image" in rec else None
    except Exception as exc:  # noqa: BLE001 - any damage is the same problem
        return f"it cannot be read ({type(exc).__name__}: {str(exc)[:200]})"
    if index != k:
        return f"it holds record {index}, not {k}"
    if seed != want_seed:
        return (f"its bed seed {seed} is not record_seed({params['seed']}, {k}) = {want_seed}: "
                "a record of another data set")
    if run is not None and not same_but_count(run, params):
        return f"it was made by another run ({describe_params(run)})"
    want_shape = get_scale(params["scale"]).image_shape
    if shape is not None and shape != tuple(want_shape):
        return f"its image has shape {shape}, scale {params['scale']} makes {tuple(want_shape)}"
    return None


def reject_part(path, output):
    """Move a refused part file into ``rejected_dir(output)``; returns its new path."""
    rejected = rejected_dir(output)
    os.makedirs(rejected, exist_ok=True)
    base = os.path.basename(path)
    dest, n = os.path.join(rejected, base), 1
    while os.path.exists(dest):
        dest, n = os.path.join(rejected, f"{base}.{n}"), n + 1
    os.replace(path, dest)
    return dest


def remove_parts(parts):
    """Remove a parts directory once its records are in the merged file."""
    shutil.rmtree(parts, ignore_errors=True)
