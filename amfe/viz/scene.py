"""What ``amfe view`` shows, decided once for every renderer (numpy only).

Finds a result's case files, picks the bond array to colour by, its clipped
range and colour-bar title, and the warp factor; the pvpython script and the
matplotlib fallback both draw exactly this (docs/viewing.md).
"""
import os
from dataclasses import dataclass

import numpy as np

from amfe.errors import AmfeError
from amfe.io.pvd import PVD_NAME, SIDECAR_NAME, read_collection
from amfe.io.vtu import WARP_SHARE, read_case, warp_factor
from amfe.version import __version__

#: ``--color`` value -> (cell array, colour-bar title with unit, signed?)
COLOR_ARRAYS = {
    "axial_force": ("axial_force_N", "axial force [N] (tension +)", True),
    "shear_force": ("shear_force_N", "shear force [N] (magnitude)", False),
    "torsion": ("torsion_Nm", "torsion [N m]", True),
    "bending_moment": ("bending_moment_Nm", "bending moment [N m] (magnitude)", False),
    "force": ("force_i_N", "|force| [N]", False),
    "moment": ("moment_i_Nm", "|moment about i| [N m]", False),
    "a_star": ("a_star", "a* = a / R_eff [-]", False),
}
PERCENTILES = (2.0, 98.0)
SPHERE_SHARE = 0.3
"""Spheres are drawn at this share of each particle's radius: at full size they
overlap (a* ~ 0.8) and hide the bonds."""
TUBE_SHARE = 0.12
"""Tube radius as a share of the mean particle radius."""
_NEEDED = ("particle_id", "radius_m", "displacement_m")


@dataclass
class Scene:
    """One load case, ready to draw.

    Attributes
    ----------
    case, label : str
        Case name (``"xx"``) and label (``"xx: eps_xx = 1"``).
    path : str
        The case file.
    points, displacement : ndarray (N, 3) [m]
        Undeformed centres; displacement per unit macro-strain.
    radius : ndarray (N,) [m]
    lines : ndarray (M, 2) int
        Point indices of each bond.
    values : ndarray (M,)
        The colour array in its unit (the magnitude of a vector array).
    color, title : str
        The ``--color`` key and its colour-bar title with unit.
    signed : bool
        The quantity has a sign (tension +); see :attr:`diverging`.
    vmin, vmax : float
        The :data:`PERCENTILES` range of ``values``.
    warp : float
        Displacement scale drawn (the largest displacement is WARP_SHARE of the box).
    """

    case: str
    label: str
    path: str
    points: np.ndarray
    displacement: np.ndarray
    radius: np.ndarray
    lines: np.ndarray
    values: np.ndarray
    color: str
    title: str
    signed: bool
    vmin: float
    vmax: float
    warp: float

    @property
    def diverging(self):
        """A diverging colour map, white at zero: a signed quantity whose range holds 0."""
        return self.signed and self.vmin < 0.0 < self.vmax

    @property
    def array(self):
        """The cell array coloured by."""
        return COLOR_ARRAYS[self.color][0]

    def summary(self):
        """One line: warp factor and colour range, as ``amfe view`` prints it."""
        return (f"case {self.case}: warp factor {self.warp:.4g} (largest displacement = "
                f"{100 * WARP_SHARE:g} % of the box); {self.title} range {self.vmin:.4g} .. "
                f"{self.vmax:.4g} ({PERCENTILES[0]:g}-{PERCENTILES[1]:g} percentile)")


def rewrite_hint(where, what):
    """The one-line refusal of files an older amfe wrote, with the command that rewrites them."""
    return (f"{where} holds {what}, which amfe {__version__} does not read; write the "
            "result again as .vtu: 'amfe homogenize BED.h5 --vtu DIR' (Python: "
            "amfe.homogenize(..., vtu_dir=DIR))")


def case_files(target):
    """The case files of a result: ``[(name, path), ...]`` in case order.

    Parameters
    ----------
    target : str
        A directory holding ``cases.pvd``, a ``.pvd`` file, or one ``case_<name>.vtu``.

    Raises
    ------
    AmfeError
        Nothing amfe wrote there, or files of an older amfe (0.2's ``.vtp``,
        0.1's ``.vtu`` without ``cases.json``): the message says how to rewrite them.
    """
    target = os.fspath(target)
    if os.path.isdir(target):
        pvd = os.path.join(target, PVD_NAME)
        if not os.path.isfile(pvd):
            if any(f.startswith("case_") and f.endswith(".vtp") for f in os.listdir(target)):
                raise AmfeError(rewrite_hint(target, ".vtp files of amfe 0.2"))
            raise AmfeError(f"{target} holds no {PVD_NAME}; write the files with "
                            "'amfe homogenize BED.h5 --vtu DIR'")
        target = pvd
    if not os.path.isfile(target):
        raise AmfeError(f"{target}: no such file or directory; give the directory of "
                        "'amfe homogenize BED.h5 --vtu DIR', its .pvd or one .vtu")
    if target.endswith(".vtp"):
        raise AmfeError(rewrite_hint(target, "a .vtp file of amfe 0.2"))
    if target.endswith(".vtu"):
        name = os.path.basename(target)[:-4]
        return [(name[5:] if name.startswith("case_") else name, os.path.abspath(target))]
    if not target.endswith(".pvd"):
        raise AmfeError(f"{target}: expected a result directory, a .pvd or a .vtu file")
    out = read_collection(target)
    if not out:
        raise AmfeError(f"{target} lists no load cases")
    if any(p.endswith(".vtp") for _, p in out):
        raise AmfeError(rewrite_hint(target, "a list of .vtp files of amfe 0.2"))
    if not os.path.isfile(os.path.join(os.path.dirname(target), SIDECAR_NAME)):
        raise AmfeError(rewrite_hint(target, f"files of an older amfe (no {SIDECAR_NAME})"))
    missing = [p for _, p in out if not os.path.isfile(p)]
    if missing:
        raise AmfeError(f"{target} lists files that are missing: {', '.join(missing)}")
    return out


def select_cases(files, case=None):
    """The entries of ``files`` named ``case`` (all of them when None)."""
    if case is None:
        return files
    picked = [f for f in files if f[0] == case]
    if not picked:
        raise AmfeError(f"--case {case!r}: the result has cases "
                        + ", ".join(n for n, _ in files))
    return picked


def check_color(color):
    """Validate a ``--color`` key; the error lists the choices."""
    if color not in COLOR_ARRAYS:
        raise AmfeError(f"--color {color!r}: choose one of " + ", ".join(COLOR_ARRAYS))
    return color


def clipped_range(values, percentiles=PERCENTILES):
    """The (lo, hi) percentiles of ``values`` (M,), widened when they coincide."""
    if values.size == 0:
        return 0.0, 1.0
    lo, hi = (float(v) for v in np.percentile(values, percentiles))
    if hi <= lo:
        pad = abs(lo) * 1e-6 or 1.0
        lo, hi = lo - pad, hi + pad
    return lo, hi


def load_scene(name, path, color):
    """Read one case file and decide how it is drawn.

    Parameters
    ----------
    name : str
        Case name.
    path : str
        Its ``.vtu``.
    color : str
        A key of :data:`COLOR_ARRAYS`.

    Returns
    -------
    Scene
    """
    array, title, signed = COLOR_ARRAYS[check_color(color)]
    data = read_case(path)
    missing = [a for a in _NEEDED if a not in data["point_data"]]
    if missing or array not in data["cell_data"]:
        raise AmfeError(f"{path} lacks the arrays {', '.join(missing or [array])}: not a case "
                        "file of 'amfe homogenize --vtu'")
    values = data["cell_data"][array]
    if values.ndim == 2:
        values = np.sqrt(np.einsum("ij,ij->i", values, values))
    disp = data["point_data"]["displacement_m"]
    label = data["field_data"].get("case_label", name)
    vmin, vmax = clipped_range(values)
    return Scene(case=name, label=label, path=path, points=data["points"], displacement=disp,
                 radius=data["point_data"]["radius_m"], lines=data["lines"], values=values,
                 color=color, title=title, signed=signed, vmin=vmin, vmax=vmax,
                 warp=warp_factor(data["points"], disp))


def png_name(outdir, case, color):
    """Output path of one picture: ``<outdir>/view_<case>_<color>.png``."""
    return os.path.join(outdir, f"view_{case}_{color}.png")
