"""A sweep's tables: one row per bed, and one per parameter point with mean, spread and count.

:class:`SweepTable` holds both as columns ({name: numpy array}), plain data with
no pandas needed (``to_pandas()`` gives DataFrames where pandas is installed).
Written as ``beds.csv``, ``points.csv`` and ``sweep.h5`` (groups /beds and
/points, a dataset per column, the spec as JSON in the root's ``spec``
attribute), each atomically. Units: moduli in Pa, lengths in m, as the JSON
results; the CSV headers name them.
"""
import csv
import io
import json
import os
from dataclasses import dataclass

import numpy as np

from amfe.io.atomic import atomic_write, atomic_write_h5
from amfe.vocab import CONSTANT_NAMES, LABEL_NAMES

#: Constants and the other per-bed numbers averaged over the seeds of a point.
AVERAGED = tuple(CONSTANT_NAMES) + ("solid_fraction", "n_particles")
UNITS = {**{n: "Pa" for n in CONSTANT_NAMES if n[0] in "EG"},
         **{n: "-" for n in CONSTANT_NAMES if n.startswith("nu")}, "solid_fraction": "-",
         "seconds": "s", "track_width": "m", "hatch_spacing": "m", "skip_length": "m",
         "offset": "m", "mean_radius": "m", "layer_thickness": "m", "angle": "deg",
         "layer_rotation": "deg", "E": "Pa"}


@dataclass
class SweepTable:
    """beds: {column: (n_beds,) array}; points: {column: (n_points,) array}; spec: the sweep's
    dict (:meth:`amfe.study.spec.SweepSpec.to_dict`)."""

    beds: dict
    points: dict
    spec: dict

    def to_pandas(self) -> tuple:
        """(beds, points) as pandas DataFrames (ImportError without pandas)."""
        import pandas as pd  # noqa: PLC0415 (heavy or optional: loaded when used)
        return pd.DataFrame(self.beds), pd.DataFrame(self.points)

    def __repr__(self) -> str:
        names = [n for n in self.spec["points"][0]]
        return (f"SweepTable({len(self.beds['index'])} beds, {len(self.points['point'])} "
                f"points over {', '.join(names)}; columns {', '.join(self.points)})")


def tables(rows, spec):
    """The :class:`SweepTable` of a sweep's rows (list of dicts, in bed order)."""
    names = list(spec["points"][0])
    columns = _columns(rows, names)
    beds = {k: _array([r.get(k) for r in rows]) for k in columns}
    points = {"point": np.arange(len(spec["points"]))}
    for n in names:
        points[n] = np.array([p[n] for p in spec["points"]], dtype=float)
    index = beds["point"]
    points["count"] = np.bincount(index, minlength=len(spec["points"]))
    for name in AVERAGED:
        if name not in beds:
            continue
        values = beds[name].astype(float)
        mean, std = [], []
        for p in points["point"]:
            v = values[(index == p) & np.isfinite(values)]
            mean.append(v.mean() if v.size else np.nan)
            std.append(v.std(ddof=1) if v.size > 1 else np.nan)
        points[f"{name}_mean"], points[f"{name}_std"] = np.array(mean), np.array(std)
    if "source" in beds:
        points["solved"] = np.bincount(index, weights=beds["source"] == "solver",
                                       minlength=len(spec["points"])).astype(int)
    return SweepTable(beds, points, spec)


def _columns(rows, names):
    """The beds table's columns: one layout for every method (solver, surrogate, surrogate
    with --fallback), a cell empty where its row has no value (a solver row has no interval,
    a surrogate row no shear modulus), then any other key a row carries."""
    layout = ["index", "point", "seed", *names, "n_particles", "solid_fraction",
              *CONSTANT_NAMES, *(f"{n}_{end}" for n in LABEL_NAMES for end in ("lo", "hi")),
              "n_removed", "warnings", "source", "flagged", "flag_reasons", "error", "seconds"]
    seen = dict.fromkeys(layout)
    for r in rows:
        for k in r:
            seen.setdefault(k, None)
    return list(seen)


def _array(values):
    if all(isinstance(v, bool) for v in values):
        return np.array(values, dtype=bool)
    if all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in values):
        return np.array(values, dtype=np.int64)
    if all(v is None or isinstance(v, (int, float)) for v in values):
        return np.array([np.nan if v is None else v for v in values], dtype=float)
    return np.array(["" if v is None else str(v) for v in values])


def write_tables(table, directory):
    """beds.csv, points.csv and sweep.h5 in ``directory``; their paths."""
    paths = []
    for name, cols in (("beds", table.beds), ("points", table.points)):
        path = os.path.join(directory, f"{name}.csv")
        text = _csv(cols)
        atomic_write(path, lambda fh, text=text: fh.write(text.encode()))
        paths.append(path)
    h5 = os.path.join(directory, "sweep.h5")

    def fill(f):
        f.attrs["spec"] = json.dumps(table.spec)
        for name, cols in (("beds", table.beds), ("points", table.points)):
            g = f.create_group(name)
            for k, v in cols.items():
                d = g.create_dataset(k, data=v.astype("S") if v.dtype.kind == "U" else v)
                if k.split("_")[0] in UNITS or k in UNITS:
                    d.attrs["unit"] = UNITS.get(k, UNITS.get(k.rsplit("_", 1)[0], ""))
    atomic_write_h5(h5, fill)
    return paths + [h5]


def _csv(cols):
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    names = list(cols)
    w.writerow([f"{n} [{_unit(n)}]" if _unit(n) else n for n in names])
    for i in range(len(next(iter(cols.values())))):
        w.writerow([_cell(cols[n][i]) for n in names])
    return out.getvalue()


def _unit(name):
    for key in (name, name.rsplit("_", 1)[0]):
        if key in UNITS:
            return UNITS[key]
    return ""


def _cell(v):
    if isinstance(v, (float, np.floating)):
        return "" if not np.isfinite(v) else repr(float(v))
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v)).lower()
    return str(v)
