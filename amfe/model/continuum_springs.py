"""Bond springs calibrated on the continuum: the paper's neck in series with a shared body.

The paper's springs (eqs. 1-4, :mod:`amfe.model.springs`) treat each neck as a
punch on two half-spaces: the particle behind a neck is infinitely large. On
a dense bed a particle carries many large necks, its body is a short column
shared among them, and the frame is stiffer than the solid of the same
spheres (docs/model.md, section 11). ``--springs continuum`` puts a body
compliance in series with each paper spring (docs/model.md, section 11, for
the derivation):

    1 / k_x = 1 / k_x^paper + beta_x (c_i + c_j),
    c_p = phi_p / (E R_p^m),   phi_p = sum over p's necks of a_k / R_p,

with m = 1 for the forces (k_n, k_t [N/m]) and m = 3 for the moments
(kappa_n, kappa_t [N m]); beta_n for k_n and the bending spring kappa_t
(normal stresses in the neck), beta_t for k_t and the torsion spring kappa_n
(shear stresses). phi_p, the necks' radii summed over the particle's radius,
is the share of the body each neck loads. At a small neck (a -> 0) the body
term is of order a / R against 1 and the springs reduce to the paper's, and so
to the rigid-punch limits (k_n -> E a / (1 - nu^2) and the others; tests).

The parameters live in one versioned file, ``amfe/models/springs_continuum.json``
(run/train/fit_continuum_springs.py writes it). Pure numpy; the element, the
assembly and the solvers do not change, only the spring values.
"""
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from amfe.errors import AmfeError

#: The parameter file's format; a file of another format is refused.
SPRINGS_FORMAT = 1
SPRING_CHOICES = ("paper", "continuum")
PARAMS_FILE = Path(__file__).resolve().parent.parent / "models" / "springs_continuum.json"


@dataclass(frozen=True)
class ContinuumSprings:
    """The two body-compliance factors of the continuum springs [-] and where they came from."""

    beta_n: float
    beta_t: float
    alpha: float = 0.0
    version: str = "unfitted"
    source: str = "given"
    #: the bed-mean neck share (:func:`neck_share`) of the beds fitted on, (lo, hi), or None
    phi_range: tuple = None
    #: the solid fractions of V's box the fit took its beds from, (lo, hi), or None (the
    #: parameter file's fit; not part of the record, nor of equality: a data set's springs
    #: compare as before)
    fraction_range: tuple = field(default=None, compare=False)

    def __post_init__(self):
        for name in ("beta_n", "beta_t", "alpha"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) \
                    or not (math.isfinite(float(value)) and float(value) >= 0.0):
                raise AmfeError(f"continuum springs: {name} must be a finite number >= 0, "
                                f"got {value!r}")
            object.__setattr__(self, name, float(value))

    def record(self) -> dict:
        """What a result's JSON says of these springs."""
        out = {"name": "continuum", "alpha": self.alpha, "beta_n": self.beta_n,
               "beta_t": self.beta_t, "version": self.version, "source": self.source}
        if self.phi_range is not None:
            out["phi_range"] = [float(v) for v in self.phi_range]
        return out


def load_params(path=None) -> ContinuumSprings:
    """The fitted :class:`ContinuumSprings` of ``path`` (default: the shipped file).

    AmfeError for a missing or unreadable file, another format, or missing values."""
    path = Path(path) if path is not None else PARAMS_FILE
    try:
        with open(path) as f:
            data = json.load(f)
    except FileNotFoundError:
        raise AmfeError(f"the continuum springs' parameters {path} are missing; fit them with "
                        "run/train/fit_continuum_springs.py") from None
    except (OSError, ValueError) as exc:
        raise AmfeError(f"cannot read the continuum springs' parameters {path}: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != SPRINGS_FORMAT:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise AmfeError(f"{path}: continuum springs of format {got!r}; this amfe reads format "
                        f"{SPRINGS_FORMAT} (upgrade amfe or refit the springs)")
    try:
        fit = data.get("fit") if isinstance(data.get("fit"), dict) else {}
        return ContinuumSprings(data["beta_n"], data["beta_t"], data["alpha"],
                                str(data["version"]), str(path.name),
                                tuple(data["phi_range"]) if "phi_range" in data else None,
                                tuple(fit["solid_fraction_range"])
                                if "solid_fraction_range" in fit else None)
    except KeyError as exc:
        raise AmfeError(f"{path}: no {exc.args[0]!r} in the continuum springs' parameters") \
            from None


def resolve_springs(value):
    """None for the paper's springs, else the :class:`ContinuumSprings` to apply.

    value: "paper", "continuum" (the shipped fit) or a ContinuumSprings (a fit's trial)."""
    if isinstance(value, ContinuumSprings):
        return value
    if value == "paper":
        return None
    if value == "continuum":
        return load_params()
    raise AmfeError(f"springs: unknown value {value!r}; choose one of {', '.join(SPRING_CHOICES)}")


def springs_record(value) -> dict:
    """The JSON record of a springs choice: {"name": "paper"} or the continuum parameters."""
    chosen = resolve_springs(value)
    return {"name": "paper"} if chosen is None else chosen.record()


def springs_of_record(record):
    """The springs choice a JSON record (:func:`springs_record`) describes: "paper" for None
    or the paper's, else the :class:`ContinuumSprings` with the recorded values. A str is
    the record as JSON text (a data set's attribute)."""
    if isinstance(record, str):
        record = json.loads(record)
    if record is None or record.get("name") == "paper":
        return "paper"
    if record.get("name") != "continuum":
        raise AmfeError(f"unknown springs record {record!r}")
    phi_range = record.get("phi_range")
    return ContinuumSprings(record["beta_n"], record["beta_t"], record.get("alpha", 0.0),
                            str(record.get("version", "unfitted")),
                            str(record.get("source", "record")),
                            None if phi_range is None else tuple(phi_range))


def neck_share(i, j, a, radii):
    """phi (n,) [-]: each particle's necks' radii summed, over its radius.

    i, j (M,) int: the bonds' particles; a (M,): their neck radii; radii (n,), same unit."""
    total = np.bincount(i, weights=a, minlength=radii.size) \
        + np.bincount(j, weights=a, minlength=radii.size)
    return total / radii


def body_springs(springs, i, j, a, radii, E, params: ContinuumSprings):
    """(k_n, k_t, kappa_n, kappa_t) of the continuum model from the paper's ``springs``.

    springs: the paper's four (M,) arrays; i, j, a (M,) and radii (n,) in one length unit,
    E in the matching stress unit (force / length^2); params: beta_n, beta_t."""
    phi = neck_share(i, j, a, radii)
    # the neck among its neighbours: stiffer by (1 + alpha phi) than alone on a half-space
    grow = 1.0 + params.alpha * 0.5 * (phi[i] + phi[j])
    k_n, k_t, kappa_n, kappa_t = (k * grow for k in springs)
    c1 = phi / (E * radii)          # per particle, times k [force/length]: dimensionless
    c3 = phi / (E * radii**3)       # times kappa [force length]
    body1, body3 = c1[i] + c1[j], c3[i] + c3[j]
    return (k_n / (1.0 + params.beta_n * k_n * body1),
            k_t / (1.0 + params.beta_t * k_t * body1),
            kappa_n / (1.0 + params.beta_t * kappa_n * body3),
            kappa_t / (1.0 + params.beta_n * kappa_t * body3))


def apply_springs(frame, springs):
    """``frame`` (amfe.model.frame.Frame) with its springs of the model ``springs``
    ("paper": unchanged; "continuum" or a :class:`ContinuumSprings`: :func:`body_springs`)."""
    params = resolve_springs(springs)
    if params is None:
        return frame
    b = frame.bonds
    # the frame's stress unit: E = 1 when non-dimensional (force_scale = E length^2)
    E = frame.material.E * frame.length_scale**2 / frame.force_scale
    k_n, k_t, kappa_n, kappa_t = body_springs(
        (frame.k_n, frame.k_t, frame.kappa_n, frame.kappa_t), b.i, b.j, b.a, frame.radii, E,
        params)
    return replace(frame, k_n=k_n, k_t=k_t, kappa_n=kappa_n, kappa_t=kappa_t)


def springs_warnings(frame, springs):
    """[str]: a warning when continuum springs are used on a bed outside the fit's range of
    bed-mean neck share (their constants are then an extrapolation); [] otherwise."""
    params = resolve_springs(springs)
    if params is None or params.phi_range is None:
        return []
    b = frame.bonds
    phi = float(neck_share(b.i, b.j, b.a, frame.radii).mean())
    lo, hi = params.phi_range
    if lo <= phi <= hi:
        return []
    return [f"the continuum springs were fitted on beds whose mean neck share (the necks' "
            f"radii over the particle's, summed) lies in [{lo:.2f}, {hi:.2f}]; this bed's is "
            f"{phi:.2f}, so its constants extrapolate the fit: check them with --model voxel "
            "(docs/model.md, section 11)"]


def fraction_warnings(fraction, springs):
    """[str]: a warning when continuum springs are used on a bed whose solid fraction of V's
    box (``fraction``, as the result's density block gives it) lies outside the fit's range;
    [] otherwise. Below it (sparse beds, a few dozen particles in a box) the frame is
    20-45 % off the continuum with either springs (docs/model.md, section 11)."""
    params = resolve_springs(springs)
    if params is None or params.fraction_range is None or fraction is None:
        return []
    lo, hi = params.fraction_range
    if lo <= fraction <= hi:
        return []
    return [f"the continuum springs hold for solid fractions {lo:g}-{hi:g} of V's box, where "
            f"they were fitted; this bed's is {fraction:.3f}, where the frame is far from the "
            "continuum with either springs (20-45 % on the moduli below 0.2): use --model voxel "
            "(docs/model.md, section 11)"]
