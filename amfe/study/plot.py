"""A sweep's plot: a constant's mean over the seeds against one parameter, with its spread.

A second parameter, if the sweep has one, gives one line per value. The bars
are one standard deviation over the seeds (not of the mean); a PNG written
atomically (matplotlib's Agg backend).
"""
import io
import os

import numpy as np

from amfe.errors import AmfeError
from amfe.io.atomic import atomic_write
from amfe.study.table import UNITS

_SCALE = {"Pa": (1e-9, "GPa"), "m": (1e3, "mm")}


def plot(table, path, y="Ex", x=None, hue=None):
    """Write the plot of ``y`` (a constant or solid_fraction) against parameter ``x`` (default
    the sweep's first), one line per value of ``hue`` (default its second, if any)."""
    names = list(table.spec["points"][0])
    x = x or names[0]
    hue = hue if hue is not None else next((n for n in names if n != x), None)
    for name, what in ((x, "parameter"), (hue, "parameter")):
        if name is not None and name not in names:
            raise AmfeError(f"sweep plot: {name!r} is not a {what} of the sweep "
                            f"({', '.join(names)})")
    if f"{y}_mean" not in table.points:
        have = sorted(k[:-5] for k in table.points if k.endswith("_mean"))
        raise AmfeError(f"sweep plot: no {y!r} in the table; choose from {', '.join(have)}")
    # The Figure and its Agg canvas, not pyplot: pyplot's import (its backends, its state)
    # took 0.27 s more of a surrogate sweep's 4 s (docs/benchmarks.md, "Parameter sweeps").
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    pts = table.points
    xs, xunit = _scaled(x, pts[x])
    fig = Figure(figsize=(6.4, 4.4), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    groups = [None] if hue is None else sorted(set(pts[hue].tolist()))
    for g in groups:
        sel = np.ones(len(xs), bool) if g is None else pts[hue] == g
        order = np.argsort(xs[sel])
        m, _ = _scaled(y, pts[f"{y}_mean"][sel][order])
        s, _ = _scaled(y, pts[f"{y}_std"][sel][order])
        label = None if g is None else f"{hue} = {_scaled(hue, np.array([g]))[0][0]:g} " \
                                       f"{_scaled(hue, np.array([g]))[1]}"
        ax.errorbar(xs[sel][order], m, yerr=np.nan_to_num(s), marker="o", capsize=3,
                    label=label)
    yunit = _scaled(y, np.zeros(1))[1]
    ax.set_xlabel(f"{x} [{xunit}]" if xunit else x)
    ax.set_ylabel(f"{y} [{yunit}]" if yunit else y)
    n = int(pts["count"].max())
    ax.set_title(f"{y}: mean and standard deviation over {n} seed(s)")
    if hue is not None:
        ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write(os.fspath(path), lambda fh: fh.write(buf.getvalue()))
    return os.fspath(path)


def preload():
    """Import what the sweep's end needs (matplotlib's Figure and Agg canvas, the PNG writer
    PIL loads at the first save, and h5py for sweep.h5): under mpirun rank 0 does it before
    its first bed, while the other ranks take more of the beds (amfe.study.run), not after
    the last."""
    import h5py  # noqa: F401  (amfe.study.table.write_tables)
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
    from matplotlib.figure import Figure  # noqa: F401

    try:
        from PIL import Image  # noqa: PLC0415 (matplotlib's PNG writer, loaded when used)
    except ImportError:   # matplotlib without PIL writes its PNGs another way
        return
    Image.preinit()


def _scaled(name, values):
    unit = UNITS.get(name, "")
    factor, shown = _SCALE.get(unit, (1.0, unit))
    return np.asarray(values, dtype=float) * factor, shown
