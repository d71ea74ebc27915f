"""``amfe view``'s fallback renderer: matplotlib 3-D on a bare machine (Agg, no display).

Draws a :class:`amfe.viz.scene.Scene`: the bonds of the warped frame as lines
coloured over the clipped range with a labelled colour bar, the undeformed
bounding box as a dashed grey outline, particles as dots sized by radius, and a
title with the case label and the warp factor. Large frames are thinned to
:data:`MAX_LINES` bonds and :data:`MAX_DOTS` particles, evenly by index
(every k-th), so a 100 000-particle bed renders in seconds; the title says so.
"""
import os

import numpy as np

from amfe.io.vtu import WARP_SHARE
from amfe.viz.scene import PERCENTILES, SPHERE_SHARE

MAX_LINES = 150_000
"""Most bonds drawn; more only fill the same pixels and cost seconds each 100 000."""
MAX_DOTS = 50_000
"""Most particles drawn."""


def _fast_lines():
    """A Line3DCollection whose projection is one numpy call for all segments.

    mplot3d's own projects segment by segment in Python: 10 s for 150 000 bonds.
    """
    from matplotlib.collections import LineCollection  # noqa: PLC0415 (heavy or optional: loaded when used)
    from mpl_toolkits.mplot3d import proj3d  # noqa: PLC0415 (heavy or optional: loaded when used)
    from mpl_toolkits.mplot3d.art3d import Line3DCollection  # noqa: PLC0415 (heavy or optional: loaded when used)

    class FastLine3DCollection(Line3DCollection):
        def set_segments(self, segments):
            self._xyz = np.asarray(segments, dtype=float).reshape(-1, 3)
            super().set_segments(segments)

        def do_3d_projection(self):
            xs, ys, zs = proj3d.proj_transform(*self._xyz.T, self.axes.M)
            LineCollection.set_segments(self, np.stack([xs, ys], axis=1).reshape(-1, 2, 2))
            return float(zs.min()) if zs.size else 1e9

    return FastLine3DCollection


def box_edges(points):
    """The 12 edges (12, 2, 3) of the axis-aligned bounding box of ``points`` (N, 3)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    c = np.array([[hi[k] if (n >> k) & 1 else lo[k] for k in range(3)] for n in range(8)])
    pairs = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
    return np.array([[c[a], c[b]] for a, b in pairs])


def _every(count, limit):
    """Index step that keeps at most ``limit`` of ``count`` items."""
    return max(1, -(-count // limit))


def render(scene, png, size=(1200, 900), dpi=100):
    """Write one PNG of ``scene``, exactly ``size`` pixels.

    Parameters
    ----------
    scene : amfe.viz.scene.Scene
    png : str
        Output path (written to a hidden temporary beside it, then renamed).
    size : (int, int)
        Width and height [pixel].
    dpi : int

    Returns
    -------
    str
        ``png``.
    """
    import matplotlib  # noqa: PLC0415 (heavy or optional: loaded when used)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 (heavy or optional: loaded when used)
    from matplotlib.colors import Normalize, TwoSlopeNorm  # noqa: PLC0415 (heavy or optional: loaded when used)
    from mpl_toolkits.mplot3d.art3d import Line3DCollection  # noqa: PLC0415 (heavy or optional: loaded when used)

    mm = 1e3                                   # axes in mm: readable ticks
    x0 = scene.points * mm
    x = x0 + scene.warp * mm * scene.displacement
    lstep = _every(len(scene.lines), MAX_LINES)
    pstep = _every(len(x), MAX_DOTS)
    fig = plt.figure(figsize=(size[0] / dpi, size[1] / dpi), dpi=dpi)
    ax = fig.add_axes([0.0, 0.0, 0.84, 0.92], projection="3d")
    if scene.diverging:                        # white at zero, blue compression, red tension
        cmap, norm = plt.get_cmap("coolwarm"), TwoSlopeNorm(0.0, scene.vmin, scene.vmax)
    else:
        cmap, norm = plt.get_cmap("viridis"), Normalize(scene.vmin, scene.vmax, clip=True)
    ax.add_collection3d(Line3DCollection(box_edges(x0), colors="0.45", linewidths=0.8,
                                         linestyles="--"))
    lines = _fast_lines()(x[scene.lines[::lstep]], cmap=cmap, norm=norm,
                          linewidths=1.2 if lstep == 1 else 0.6)
    lines.set_array(scene.values[::lstep])
    ax.add_collection3d(lines)
    lo, hi = np.minimum(x.min(0), x0.min(0)), np.maximum(x.max(0), x0.max(0))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo)
    # dot area ~ pi (SPHERE_SHARE R)^2 in points^2, from the axes' width in mm
    pt_per_mm = 0.84 * size[0] / dpi * 72 / float(np.max(hi - lo)) * 0.5
    ax.scatter(*x[::pstep].T, s=(SPHERE_SHARE * scene.radius[::pstep] * mm * pt_per_mm) ** 2
               * np.pi, c="0.25", alpha=0.5, linewidths=0, depthshade=False)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_zlabel("z [mm]")
    ax.view_init(elev=25, azim=-60)
    thinned = (f"; 1 in {lstep} bonds and 1 in {pstep} particles drawn"
               if max(lstep, pstep) > 1 else "")
    ax.set_title(f"case {scene.label}\ndisplacement x {scene.warp:.3g} (largest = "
                 f"{100 * WARP_SHARE:g} % of box); dashed: undeformed box{thinned}", fontsize=10)
    bar = fig.colorbar(lines, cax=fig.add_axes([0.87, 0.15, 0.025, 0.7]), extend="both")
    bar.ax.set_yscale("linear")                # a diverging bar in proportion to the values
    bar.set_label(f"{scene.title}, {PERCENTILES[0]:g}-{PERCENTILES[1]:g} percentile range")
    tmp = os.path.join(os.path.dirname(os.path.abspath(png)), f".{os.path.basename(png)}.tmp.png")
    try:
        fig.savefig(tmp, dpi=dpi)
        os.replace(tmp, png)
    finally:
        plt.close(fig)
        if os.path.exists(tmp):
            os.remove(tmp)
    return png
