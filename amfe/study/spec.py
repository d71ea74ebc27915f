"""What a sweep is: a grid or list of parameter points, times seeds, on one base bed.

A point sets some of the generation parameters of :func:`amfe.generate_bed`
(the scan path's, the powder's) and of the material; every other parameter is
the base bed's (``amfe pack``'s defaults, or the sweep's own ``base``). Bed k of
the sweep is point ``k // n_seeds`` with seed ``seeds[k % n_seeds]``: the same
seeds at every point, so that two points differ by their parameters and not by
their lattices (common random numbers). Lengths are in metres here; the
command line and the TOML file take them with a unit (``0.1mm``) or bare in mm
(:mod:`amfe.io.units`).
"""
import itertools
import json
import math
import tomllib
from dataclasses import asdict, dataclass, field

from amfe.errors import AmfeError
from amfe.io.units import parse_length
from amfe.model.continuum_springs import SPRING_CHOICES

#: Parameters a point may set, and how each is read: a length (bare in mm), a number.
SCAN = ("track_width", "hatch_spacing", "angle", "layer_rotation", "skip_fraction",
        "skip_length", "offset")
POWDER = ("mean_radius", "jitter", "layer_thickness", "a_star_max", "enlargement_hi")
MATERIAL = ("E", "nu", "psi")
LENGTHS = ("track_width", "hatch_spacing", "skip_length", "offset", "mean_radius",
           "layer_thickness")
PARAMETERS = SCAN + POWDER + MATERIAL
METHODS = ("solver", "surrogate")


@dataclass(frozen=True)
class SweepSpec:
    """A sweep, checked when made.

    points: tuple of {parameter: value} (SI), the same keys in every point;
    seeds: tuple of int bed seeds; size (3,) [m]: the beds' box; method:
    "solver" (amfe.homogenize) or "surrogate" (the shipped model, ``fallback``:
    its flagged beds solved); solver, rtol, ranks_per_bed: the solve's; springs: the bond
    springs, "paper" or "continuum" (the solves', and the surrogate's model of them);
    flag_share: the share of its calibration beds that the 0.6 mm model's risk flag flags
    (None: its own, 0.19; as ``amfe predict --flag-share``).
    """

    points: tuple
    seeds: tuple
    size: tuple = (0.6e-3, 0.6e-3, 0.3e-3)
    method: str = "solver"
    fallback: bool = False
    solver: str = "auto"
    rtol: float = None
    ranks_per_bed: int = 1
    base: dict = field(default_factory=dict)
    springs: str = "paper"
    flag_share: float = None

    def __post_init__(self):
        if not self.points:
            raise AmfeError("sweep: no parameter point (give --grid NAME=V1,V2 or a file)")
        keys = set(self.points[0])
        for p in self.points:
            if set(p) != keys:
                raise AmfeError(f"sweep: every point must set the same parameters, got "
                                f"{sorted(keys)} and {sorted(p)}")
            for name, value in p.items():
                _check(name, value)
        if not self.seeds or not all(isinstance(s, int) and 0 <= s < 2**63 for s in self.seeds):
            raise AmfeError(f"sweep: seeds must be integers >= 0, got {self.seeds!r}")
        if len(set(self.seeds)) != len(self.seeds):
            raise AmfeError(f"sweep: a seed is repeated: {self.seeds!r}")
        if self.method not in METHODS:
            raise AmfeError(f"sweep: method must be one of {', '.join(METHODS)}, got "
                            f"{self.method!r}")
        if self.fallback and self.method != "surrogate":
            raise AmfeError("sweep: --fallback solves the surrogate's flagged beds; it needs "
                            "--method surrogate")
        for name, value in self.base.items():
            _check(name, value)
        if self.springs not in SPRING_CHOICES:
            raise AmfeError(f"sweep: springs must be one of {', '.join(SPRING_CHOICES)}, got "
                            f"{self.springs!r}")
        if self.flag_share is not None:
            if self.method != "surrogate":
                raise AmfeError("sweep: a flag share sets the surrogate's flag; it needs "
                                "--method surrogate")
            # scipy's import only when a share is given
            from amfe.training.flagrisk import check_share

            try:
                check_share(self.flag_share)
            except AmfeError as exc:
                raise AmfeError(f"sweep: {exc}") from None
        if not (isinstance(self.ranks_per_bed, int) and self.ranks_per_bed >= 1):
            raise AmfeError(f"sweep: ranks per bed must be a positive integer, got "
                            f"{self.ranks_per_bed!r}")

    @property
    def names(self):
        """The parameters the points set, in their order."""
        return tuple(self.points[0])

    @property
    def n_beds(self):
        return len(self.points) * len(self.seeds)

    def bed(self, k):
        """(point index, seed) of bed k."""
        return divmod(k, len(self.seeds))[0], self.seeds[k % len(self.seeds)]

    def to_dict(self):
        out = {**asdict(self), "points": [dict(p) for p in self.points],
               "seeds": list(self.seeds), "size": list(self.size)}
        if self.springs == "paper":   # a sweep from before --springs keeps its fingerprint
            del out["springs"]
        if self.flag_share is None:   # and one from before --flag-share
            del out["flag_share"]
        return out

    def fingerprint(self):
        """A JSON string that names the sweep: its beds and how they are solved."""
        return json.dumps(self.to_dict(), sort_keys=True)


def _check(name, value):
    if name not in PARAMETERS:
        raise AmfeError(f"sweep: unknown parameter {name!r}; choose from {', '.join(PARAMETERS)}")
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise AmfeError(f"sweep: {name} must be a finite number, got {value!r}")


def read_value(name, text):
    """A parameter's value from text: a length with a unit or bare in mm (as SI), or a number."""
    if name not in PARAMETERS:
        raise AmfeError(f"sweep: unknown parameter {name!r}; choose from {', '.join(PARAMETERS)}")
    try:
        if name in LENGTHS:   # in decimal to metres, as amfe pack converts its millimetres
            text = str(text).strip()
            bare = text and (text[-1].isdigit() or text[-1] == ".")
            return parse_length(text + "mm" if bare else text, "m")
        return float(text)
    except ValueError as exc:
        raise AmfeError(f"sweep: {name}: {exc}") from None


def grid(axes):
    """Points of the full grid of ``axes`` [(name, [values])], the last axis fastest."""
    names = [n for n, _ in axes]
    if len(set(names)) != len(names):
        raise AmfeError(f"sweep: a parameter is given twice: {names}")
    return tuple(dict(zip(names, combo)) for combo in itertools.product(*(v for _, v in axes)))


def parse_grid_args(items):
    """[(name, values)] from --grid NAME=V1,V2,... arguments (values read by read_value)."""
    axes = []
    for item in items:
        name, sep, values = item.partition("=")
        if not sep or not values:
            raise AmfeError(f"sweep: --grid takes NAME=V1,V2,..., got {item!r}")
        name = name.strip().replace("-", "_")
        axes.append((name, [read_value(name, v) for v in values.split(",")]))
    return axes


def read_spec_file(path):
    """The keyword arguments of :class:`SweepSpec` from a TOML file.

    [grid] NAME = [values] gives the full grid; [[point]] tables a list of
    points instead; seeds = N (0..N-1) or [list]; size = [x, y, z]; method,
    fallback, solver, rtol, ranks_per_bed, springs, flag_share; [base] NAME = value. Lengths are
    strings with a unit ("0.1mm") or numbers in mm.
    """
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise AmfeError(f"sweep: {path} does not exist") from None
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise AmfeError(f"sweep: cannot read {path} as TOML: {exc}") from None
    unknown = set(data) - {"grid", "point", "seeds", "size", "method", "fallback", "solver",
                           "rtol", "ranks_per_bed", "base", "springs", "flag_share"}
    if unknown:
        raise AmfeError(f"sweep: {path}: unknown keys {sorted(unknown)}")
    if ("grid" in data) == ("point" in data):
        raise AmfeError(f"sweep: {path} needs either a [grid] table or [[point]] tables")
    if "grid" in data:
        points = grid([(n, [read_value(n, v) for v in _as_list(vs)])
                       for n, vs in data["grid"].items()])
    else:
        points = tuple({n: read_value(n, v) for n, v in p.items()} for p in data["point"])
    out = {"points": points, "seeds": seeds_of(data.get("seeds", 4))}
    if "size" in data:
        out["size"] = tuple(read_value("track_width", v) for v in data["size"])
    if "base" in data:
        out["base"] = {n: read_value(n, v) for n, v in data["base"].items()}
    for key in ("method", "fallback", "solver", "rtol", "ranks_per_bed", "springs",
                "flag_share"):
        if key in data:
            out[key] = data[key]
    return out


def _as_list(values):
    return values if isinstance(values, list) else [values]


def seeds_of(value):
    """Seeds from N (0..N-1) or a list of ints."""
    if isinstance(value, int) and not isinstance(value, bool):
        if value < 1:
            raise AmfeError(f"sweep: the number of seeds must be at least 1, got {value}")
        return tuple(range(value))
    if isinstance(value, (list, tuple)) and all(isinstance(s, int) for s in value):
        return tuple(value)
    raise AmfeError(f"sweep: seeds must be a count or a list of integers, got {value!r}")
