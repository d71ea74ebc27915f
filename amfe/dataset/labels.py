"""Label tables: a data set's labels without its images, to rebuild it without solving.

A record's bed and images are a pure function of (scale, data-set seed, k)
(:mod:`amfe.model.scales`); only its labels cost a solve. A label table
(docs/datasets.md, "Label tables") keeps what a rebuild cannot recompute:

    root attrs  format "amfe.labels", format_version, scale, dataset_seed, rtol,
                solver (the request: auto, gamg, ...), bc, amfe_version (of the
                labelling run), label_rule_version, imaging_version, first, count
    bed_seed    (n,) int64    record_seed(dataset_seed, index)
    index       (n,) int64    record numbers, first..first+n-1
    C           (n, 6, 6) float64  stiffness [Pa] (NaN for failed records)
    status      (n,) uint8    0 ok, 1 failed;  reason (n,) UTF-8 bytes (fixed length)
    solver      (n,) bytes    the labelling method: the record's solver JSON with
                              only the keys of :data:`KEPT`
    n_removed, n_bonds (n,) int64, volume (n,) float64 [m^3]: the solve's frame
    bed_digest  (n,) S32      :func:`bed_digest` of the regenerated bed ("" if none)

Written once (a table is never rewritten: a new shard is a new file), gzip'ed,
with ``track_times=False`` and no date, so the same records give the same
bytes; at most :data:`MAX_TABLE_BYTES`. :func:`export_labels` writes one,
:func:`rebuild_record` is a record of ``amfe dataset --from-labels``.
"""
import glob
import hashlib
import json
import os
from dataclasses import replace

import numpy as np

from amfe.dataset.datacheck import check_dataset
from amfe.dataset.images import IMAGING_VERSION
from amfe.dataset.parts import LABEL_RULE_VERSION, STATUS_FAILED, STATUS_OK
from amfe.dataset.plan import MAX_COUNT
from amfe.dataset.record import MachineFault, regenerate
from amfe.errors import AmfeError, _list_items
from amfe.io.atomic import atomic_write_h5
from amfe.io.h5damage import damaged
from amfe.model.averages import compliance_and_constants
from amfe.model.continuum_springs import springs_of_record
from amfe.model.scales import bed_for, record_seed
from amfe.vocab import LABEL_NAMES

TABLE_FORMAT = "amfe.labels"
TABLE_FORMAT_VERSION = 1
MAX_TABLE_BYTES = 20 * 2**20
#: Root attributes that must agree between the shards of one table and its rebuild.
IDENTITY = ("scale", "dataset_seed", "rtol", "solver", "bc", "label_rule_version",
            "imaging_version", "springs")
#: Keys of a record's solver JSON that a table keeps: the method and why. Not kept: timings,
#: iteration counts, residuals and round-off checks (they differ run to run, and their
#: digits would triple a table's size).
KEPT = ("method", "requested", "reason", "ksp_type", "pc_type", "rtol", "notes")
_INT_ROWS = ("bed_seed", "index", "n_removed", "n_bonds")
_CHUNK_ROWS = 4096
_TEXT_ROWS = ("reason", "solver", "bed_digest")


def bed_digest(bed):
    """32 hex digits of BLAKE2b over the bed's centres and radii (float64, C order)."""
    h = hashlib.blake2b(digest_size=16)
    h.update(np.ascontiguousarray(bed.centers, np.float64).tobytes())
    h.update(np.ascontiguousarray(bed.radii, np.float64).tobytes())
    return h.hexdigest()


def kept_solver(text):
    """A record's solver JSON with only the keys a table keeps (:data:`KEPT`)."""
    if not text:
        return ""
    rec = json.loads(text)
    return json.dumps({k: rec[k] for k in KEPT if k in rec}, sort_keys=True)


# ---------------------------------------------------------------- export

def export_labels(data_path, output, count=None):
    """Write the label table of data set ``data_path``; returns (path written, first, end).

    ``output``: a file (records 0..count-1, default all) or an existing
    directory: then a new shard holding the records after those of the
    directory's shards of the same data set (up to ``count``), named
    SCALE_seedS_labels_FIRST-END.h5. Each bed is regenerated from its seed
    (about 0.02 s a `small` bed) for its digest, and must have the particle
    count the data set records. AmfeError for an invalid data set, a bed that
    does not regenerate, an existing table file, nothing to export, or a
    table over :data:`MAX_TABLE_BYTES`.
    """
    problems, data, attrs = check_dataset(data_path)
    if problems:
        raise AmfeError(f"{data_path} is not a valid data set ({'; '.join(problems[:3])})")
    ident = _identity(attrs)
    M = data["index"].shape[0]
    end = M if count is None else int(count)
    if not 1 <= end <= M:
        raise AmfeError(f"--count must lie in [1, {M}] (the records of {data_path}), got {count}")
    first = 0
    if os.path.isdir(output):
        first = _shard_end(output, ident)
        if first >= end:
            raise AmfeError(f"the shards in {output} already hold records 0..{first - 1} of "
                            f"{data_path}; nothing to export")
        # continuum-spring labels are named apart: a shard never looks like the paper's
        springs = "_continuum" if "springs" in ident else ""
        output = os.path.join(output, f"{ident['scale']}{springs}_seed{ident['dataset_seed']}"
                                      f"_labels_{first:08d}-{end:08d}.h5")
    if os.path.exists(output):
        raise AmfeError(f"{output} exists: a label table is written once (write a new shard)")
    rows = _rows(data, first, end, data_path, ident)
    table_attrs = {**ident, "format": TABLE_FORMAT, "format_version": TABLE_FORMAT_VERSION,
                   "amfe_version": str(attrs.get("amfe_version", "")), "first": first,
                   "count": end - first}
    atomic_write_h5(output, lambda f: _write_table(f, rows, table_attrs), check=_size_check)
    return output, first, end


def _identity(attrs):
    """A data set's attributes that a table keeps, with files' defaults for older ones."""
    return {"scale": str(attrs["scale"]), "dataset_seed": int(attrs["seed"]),
            "rtol": float(attrs["rtol"]), "solver": str(attrs.get("solver", "gamg")),
            "bc": str(attrs.get("bc", "kubc")),
            "label_rule_version": int(attrs.get("label_rule_version", 1)),
            "imaging_version": int(attrs.get("imaging_version", 1)),
            # only a data set of other springs than the paper's records them (run_params)
            **({"springs": str(attrs["springs"])} if "springs" in attrs else {})}


def _rows(data, first, end, data_path, ident):
    """The table's datasets for records first..end-1 of a data set (beds regenerated)."""
    sl = slice(first, end)
    digests = []
    for k, seed, n in zip(data["index"][sl], data["seed"][sl], data["n_particles"][sl]):
        try:
            bed = bed_for(ident["scale"], int(seed))
        except AmfeError:
            bed = None
        if (bed.n if bed is not None else -1) != int(n):
            raise AmfeError(f"record {int(k)} of {data_path} (bed seed {int(seed)}) does not "
                            f"regenerate: {'no bed' if bed is None else f'{bed.n} particles'}, "
                            f"the file says {int(n)}; the generator has changed since")
        digests.append(bed_digest(bed) if bed is not None else "")
    return {"bed_seed": data["seed"][sl], "index": data["index"][sl], "C": data["C"][sl],
            "status": data["status"][sl], "reason": data["reason"][sl].astype(str),
            "solver": np.array([kept_solver(s) for s in data["solver"][sl]], dtype=object),
            "n_removed": data["n_removed"][sl], "n_bonds": data["n_bonds"][sl],
            "volume": data["volume"][sl], "bed_digest": np.array(digests, dtype="S32")}


def _write_table(f, rows, attrs):
    for name, arr in rows.items():
        if arr.dtype.kind in "OU":
            # fixed-length UTF-8, so that gzip sees the strings (variable-length ones sit
            # uncompressed in the global heap: 330 B a record instead of ~40)
            arr = np.array([str(v).encode() for v in arr])
        elif name in _INT_ROWS:
            arr = arr.astype(np.int64)
        chunks = (max(1, min(arr.shape[0], _CHUNK_ROWS)), *arr.shape[1:])
        f.create_dataset(name, data=arr, chunks=chunks, compression="gzip", compression_opts=9,
                         shuffle=True, track_times=False)
    f["C"].attrs["units"] = "Pa"
    f["volume"].attrs["units"] = "m^3"
    f.attrs.update(attrs)


def _size_check(tmp):
    size = os.path.getsize(tmp)
    if size > MAX_TABLE_BYTES:
        raise AmfeError(f"the label table would be {size / 2**20:.1f} MB, over the "
                        f"{MAX_TABLE_BYTES / 2**20:.0f} MB of a table: export fewer records "
                        "(--count) into a directory of shards")


def _shard_end(directory, ident):
    """The end of the records held in a row from 0 by ``directory``'s shards of ``ident``."""
    held = []
    for path in sorted(glob.glob(os.path.join(directory, "*labels*.h5"))):
        attrs = _read_attrs(path)
        if all(attrs.get(k) == v for k, v in ident.items()):
            held.append((int(attrs["first"]), int(attrs["first"]) + int(attrs["count"])))
    end = 0
    for lo, hi in sorted(held):
        if lo > end:
            break
        end = max(end, hi)
    return end


#: What to do with a label shard HDF5 cannot read (:func:`amfe.io.h5damage.damaged`).
TABLE_FIX = ("export it again from its data set (amfe dataset --export-labels DATA.h5 -o "
             "LABELS.h5), or restore it from a copy")


def _read_attrs(path):
    import h5py

    with damaged(path, "label table", TABLE_FIX), h5py.File(path, "r") as f:
        return {k: (v.decode() if isinstance(v, bytes) else
                    v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}


# ---------------------------------------------------------------- read

def read_tables(paths):
    """The shards ``paths`` of one label table, joined: a dict of arrays by record, and "attrs".

    The shards must be tables (format), agree in :data:`IDENTITY`, and hold
    records 0..n-1 exactly once between them, each with bed seed
    record_seed(dataset_seed, k); their label rule and imaging must be this
    amfe's (a data set is never made of two). AmfeError otherwise, naming the
    file.
    """
    import h5py

    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    parts, ident = [], None
    for path in paths:
        attrs = _read_attrs(path) if os.path.isfile(path) else None
        if attrs is None or attrs.get("format") != TABLE_FORMAT:
            raise AmfeError(f"{path} is not an amfe label table (amfe dataset --export-labels)")
        mine = {k: attrs.get(k) for k in IDENTITY}
        if ident is not None and mine != ident:
            raise AmfeError(f"{path} is a table of another data set or method ({_describe(mine)}) "
                            f"than {paths[0]} ({_describe(ident)})")
        ident = mine
        with damaged(path, "label table", TABLE_FIX), h5py.File(path, "r") as f:
            parts.append({n: f[n][()] for n in f})
        lacking = [n for n in ("index", "bed_seed") if n not in parts[-1]]
        if lacking or (len(parts) > 1 and set(parts[-1]) != set(parts[0])):
            raise AmfeError(f"{path} is not a complete label table: "
                            + (f"it has no /{', /'.join(lacking)}" if lacking else
                               f"its datasets differ from {paths[0]}'s")
                            + f"; {TABLE_FIX}")
    _check_versions(paths[0], ident)
    table = {n: np.concatenate([p[n] for p in parts]) for n in parts[0]}
    order = np.argsort(table["index"], kind="stable")
    table = {n: a[order] for n, a in table.items()}
    n = table["index"].shape[0]
    if not np.array_equal(table["index"], np.arange(n)):
        missing = np.setdiff1d(np.arange(int(table["index"].max(initial=-1)) + 1), table["index"])
        twice = np.unique(table["index"][1:][np.diff(table["index"]) == 0])
        what = "; ".join(f"{word}: {_list_items(a.tolist(), 8)}" for word, a in (
            ("missing", missing), ("held by more than one shard", twice)) if a.size)
        top = int(table["index"].max(initial=-1))
        raise AmfeError(f"the tables {', '.join(map(str, paths))} do not hold records 0..{top} "
                        f"once each ({what}); give every shard from the first, each once "
                        "(shards of one data set do not overlap)")
    seeds = np.array([record_seed(ident["dataset_seed"], k) for k in range(n)])
    bad = np.flatnonzero(seeds != table["bed_seed"])
    if bad.size:
        raise AmfeError(f"bed seeds of records {_list_items(bad.tolist(), 8)} in the tables are "
                        f"not record_seed({ident['dataset_seed']}, k): damaged tables")
    for name in _TEXT_ROWS:
        table[name] = np.array([v.decode() for v in table[name]], dtype=object)
    table["attrs"] = {**ident, "paths": [os.fspath(p) for p in paths]}
    return table


def _check_versions(path, ident):
    if ident["imaging_version"] != IMAGING_VERSION:
        raise AmfeError(f"{path} was made with imaging version {ident['imaging_version']}, "
                        f"this amfe images with version {IMAGING_VERSION}: its rebuild would mix "
                        "images of another imaging with its labels; rebuild it with an amfe of "
                        "that imaging version")
    if ident["label_rule_version"] != LABEL_RULE_VERSION:
        raise AmfeError(f"{path} holds labels of label rule {ident['label_rule_version']}, this "
                        f"amfe labels with rule {LABEL_RULE_VERSION}: relabel its beds "
                        "(amfe dataset) instead of rebuilding them")


def _describe(ident):
    return ", ".join(f"{k} {ident.get(k)}" for k in IDENTITY if k != "springs" or ident.get(k))


# ---------------------------------------------------------------- rebuild

def table_run(table, count, solve_rest=False):
    """The record count of a rebuild of ``table`` (all its records for None).

    With ``solve_rest`` the count may pass the tables' records: the records
    beyond them are solved (a labelling run continued from its tables).
    """
    n = table["index"].shape[0]
    if count is None:
        return n
    top = MAX_COUNT if solve_rest else n
    if not isinstance(count, (int, np.integer)) or not 1 <= count <= top:
        more = "" if solve_rest else "; --solve-rest solves the records beyond them"
        raise AmfeError(f"--count must lie in [1, {top}] (the records of the label tables"
                        f"{more}), got {count}")
    return int(count)


def table_options(table, opts):
    """``opts`` (amfe.dataset.plan.DatasetOptions) with the table's scale, seed and method."""
    a = table["attrs"]
    return replace(opts, scale=a["scale"], seed=int(a["dataset_seed"]), rtol=float(a["rtol"]),
                   solver=a["solver"], bc=a["bc"], ranks_per_bed=1,
                   springs=springs_of_record(a.get("springs")))


def table_params(table, count):
    """What a rebuilt data set's run parameters add: the tables it came from, and
    the first record solved rather than rebuilt (when the count passes them)."""
    a = table["attrs"]
    params = {"from_labels": ", ".join(os.path.basename(p) for p in a["paths"]),
              "label_rule_version": int(a["label_rule_version"])}
    n = table["index"].shape[0]
    if count > n:
        params["solved_from"] = int(n)
    return params


def rebuild_record(k, table, sc, group, pixelate):
    """Record k of the data set of ``table``, without a solve: (record, None) or (None, why).

    The bed and images are regenerated (:func:`amfe.dataset.record.regenerate`)
    and the bed checked against the table's digest; C, status, reason,
    n_removed, n_bonds, volume and the method come from the table; the labels
    are recomputed from C (amfe.model.averages, as the solve does). Iterations
    stay -1 and the solve's seconds 0 (not kept). ``why``: the record's bed
    does not regenerate (another generator), or its images fail now.
    """
    rec, bed, err = regenerate(k, int(table["attrs"]["dataset_seed"]), sc, group, pixelate)
    where = f"record {k} (bed seed {rec['seed']}) of {', '.join(table['attrs']['paths'])}"
    if isinstance(err, MachineFault):
        return None, (f"{where} met an error of the machine, not of its bed ({err}): fix the "
                      "cause and run the same command again")
    digest, want = (bed_digest(bed) if bed is not None else ""), table["bed_digest"][k]
    if digest != want:
        return None, (f"{where} does not regenerate: its bed's digest is {digest or 'none'}, the "
                      f"table's {want or 'none'}; the tables are refused (the bed generator "
                      "has changed since they were made)")
    status = int(table["status"][k])
    if status == STATUS_OK and err is not None:
        return None, f"{where}: its images cannot be made now ({err})"
    rec.update(status=status, reason=str(table["reason"][k]), C=np.array(table["C"][k]),
               n_removed=int(table["n_removed"][k]), n_bonds=int(table["n_bonds"][k]),
               volume=float(table["volume"][k]), solver=str(table["solver"][k]))
    if status == STATUS_OK:
        props = compliance_and_constants(rec["C"])[1]
        rec["labels"] = np.array([float(props[n]) for n in LABEL_NAMES])
    elif status != STATUS_FAILED:
        return None, f"{where} has an unknown status {status}"
    return rec, None
