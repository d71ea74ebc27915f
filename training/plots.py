"""Learning curves as PNG (matplotlib, Agg backend), and axis helpers the docs' plots share.

The helpers make a figure read at a glance: plain percentages on a log axis
(``20 %``, not ``2 x 10^1``), whole-number epoch ticks, and rtol labels that
do not sit on top of one another. run/report/write.py uses them too.
"""
import math
import os

import numpy as np

from amfe.io.atomic import atomic_write
from amfe.vocab import LABEL_NAMES


def plain_log_axis(axis, suffix="", max_ticks=8):
    """Label a log axis with plain numbers (``0.5``, ``20 %`` with suffix " %"), not 2 x 10^1.

    Ticks are the 1-9 (or 1-2-3-5, 1-2-5, 1-3, 1) sequence inside the current view, the
    densest that gives at most ``max_ticks``; call after the data are drawn.
    axis: a matplotlib Axis (``ax.yaxis``); suffix: appended to each label (a unit).
    """
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter  # noqa: PLC0415 (heavy or optional: loaded when used)

    lo, hi = sorted(axis.get_view_interval())
    lo = max(lo, 1e-300)
    decades = range(math.floor(math.log10(lo)) - 1, math.ceil(math.log10(hi)) + 1)
    for mults in (range(1, 10), (1, 2, 3, 5), (1, 2, 5), (1, 3), (1,)):
        ticks = [m * 10.0 ** e for e in decades for m in mults if lo <= m * 10.0 ** e <= hi]
        if len(ticks) <= max_ticks:
            break
    axis.set_major_locator(FixedLocator(ticks))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.6g}{suffix}"))
    axis.set_minor_formatter(NullFormatter())   # minor ticks stay, unlabelled


def spread_labels(ax, points, texts, colors=None, **kw):
    """Annotate points, moving each label to the first offset where it covers nothing.

    points: [(x, y)] in data units; texts: one string per point; colors: one
    per point (default black). A label must not overlap a label already
    placed nor cover a marker or line of ``ax``, so call after the data and
    the axes limits are final. kw: passed to ``ax.annotate`` (fontsize...).
    """
    renderer = ax.figure.canvas.get_renderer()
    ink = _line_pixels(ax)
    placed = []
    for i, ((x, y), s) in enumerate(zip(points, texts)):
        for k, off in enumerate(_OFFSETS):
            a = ax.annotate(s, (x, y), xytext=off, textcoords="offset points",
                            color=colors[i] if colors else "k", **kw)
            box = a.get_window_extent(renderer).padded(2)
            if k == len(_OFFSETS) - 1 or not (box.count_contains(ink)
                                              or any(box.overlaps(b) for b in placed)):
                placed.append(box)
                break
            a.remove()


def _line_pixels(ax, step=2.0):
    """Display coordinates [px] along every drawn line of ax, every ``step`` px, markers widened."""
    out = [np.empty((0, 2))]
    for ln in ax.lines:
        xy = ax.transData.transform(ln.get_xydata())
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if len(xy) == 0:
            continue
        r = 0.5 * ln.get_markersize() * ax.figure.dpi / 72 if ln.get_marker() not in (
            None, "", "None", " ") else 0.0
        out += [xy + [dx, dy] for dx in (-r, 0, r) for dy in (-r, 0, r)]
        if ln.get_linestyle() not in ("None", "", " "):
            for p, q in zip(xy[:-1], xy[1:]):
                n = int(np.hypot(*(q - p)) / step) + 2
                out.append(p + np.linspace(0, 1, n)[:, None] * (q - p))
    return np.concatenate(out)


# label offsets in points, tried in order: upper right first, then around the point
_OFFSETS = ((4, 3), (4, -9), (-26, 3), (-26, -9), (7, -3), (-30, -3), (-10, 7), (-10, -13),
            (10, 9), (10, -15), (-34, 9), (-34, -15), (14, -3), (-38, -3))


def integer_epochs(ax):
    """Epoch axis: whole-number ticks only (a short run must not show epoch 2.5)."""
    from matplotlib.ticker import MaxNLocator  # noqa: PLC0415 (heavy or optional: loaded when used)

    ax.xaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 2.5, 5, 10]))
    ax.set_xlabel("epoch")


def plot_learning_curves(runs, path, title=""):
    """Write a PNG: loss (train solid, validation dashed) and validation mean relative error.

    runs: {name: history} or {name: [histories]} (an ensemble: every member
    drawn, the first labelled); a history is amfe.training.train's dict.
    """
    import matplotlib  # noqa: PLC0415 (heavy or optional: loaded when used)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 (heavy or optional: loaded when used)
    from matplotlib.lines import Line2D  # noqa: PLC0415 (heavy or optional: loaded when used)

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    n_members = 1
    for c, (name, hists) in enumerate(runs.items()):
        hists = hists if isinstance(hists, list) else [hists]
        n_members = max(n_members, len(hists))
        col = colors[c % len(colors)]
        for k, h in enumerate(hists):
            ep = np.arange(1, len(h["train_loss"]) + 1)
            alpha = 1.0 if k == 0 else 0.35
            ax1.semilogy(ep, h["train_loss"], color=col, alpha=alpha)
            if h["val_loss"]:
                ax1.semilogy(ep, h["val_loss"], "--", color=col, alpha=alpha)
        h = hists[0]
        if h["val_mre"]:
            err = 100 * np.asarray(h["val_mre"])
            ep = np.arange(1, len(err) + 1)
            if len(runs) == 1:
                for j, prop in enumerate(LABEL_NAMES):
                    ax2.semilogy(ep, err[:, j], label=prop)
            else:
                ax2.semilogy(ep, err[:, :3].mean(1), color=col, label=f"{name} moduli")
                ax2.semilogy(ep, err[:, 3:].mean(1), ":", color=col,
                             label=f"{name} Poisson ratios")
    # the loss legend: one entry per run (its colour), then what the line styles mean
    keys = [Line2D([], [], color=colors[c % len(colors)], label=name)
            for c, name in enumerate(runs)] if len(runs) > 1 else []
    keys += [Line2D([], [], color="k", label="train"),
             Line2D([], [], color="k", ls="--", label="validation")]
    if n_members > 1:
        keys.append(Line2D([], [], color="k", alpha=0.35,
                           label=f"members 2-{n_members} (validation panel: member 1)"))
    ax1.legend(handles=keys, fontsize=7)
    ax1.set_ylabel("MSE of the normalised labels")
    ax1.set_title(next(iter(runs)) + ": loss" if len(runs) == 1 else "loss")
    ax2.set_ylabel("validation mean relative error")
    ax2.set_title("validation error per property")
    ax2.legend(fontsize=7, ncol=2)
    for ax in (ax1, ax2):
        integer_epochs(ax)
        ax.grid(True, which="both", alpha=0.3)
    plain_log_axis(ax1.yaxis)
    if ax2.lines:
        plain_log_axis(ax2.yaxis, " %")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(os.fspath(path))), exist_ok=True)
    fmt = os.path.splitext(os.fspath(path))[1].lstrip(".").lower() or "png"
    try:   # atomically: an interrupted or failed write leaves no half picture
        atomic_write(path, lambda fh: fig.savefig(fh, dpi=110, format=fmt))
    finally:
        plt.close(fig)
    return path
