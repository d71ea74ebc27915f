"""What a JSON result says about itself: the header every ``amfe homogenize`` and
``amfe predict`` result carries, and the JSON Schema they follow (``result_schema.json``).

The header: ``schema_version``, ``command``, ``amfe_version``, ``input`` (path
and a content hash of the bed), ``material`` (E, nu, psi and where they
came from), ``box``, ``units``, ``counts`` (particles and bonds, in the
input and kept), the Poisson convention and the units of C and S.
"""
import hashlib
import json
from importlib import resources

import numpy as np

from amfe.errors import AmfeError
from amfe.model.bonds import find_pairs
from amfe.model.conditions import CONDITIONS, condition_names
from amfe.version import __version__
from amfe.vocab import CASE_NAMES

#: Version of the JSON layout; bumped when a key changes meaning or goes away, or a
#: required key is added (3: the self-describing header of this module; 4: volume is the
#: bed's box and n_removed counts the pieces the condition does not load, issue 30; 5:
#: homogenize's volume_box and density, issue 48).
SCHEMA_VERSION = 5
SCHEMA_FILE = "result_schema.json"
POISSON_CONVENTION = ("nu_ij = -S_ji / S_ii: lateral strain in j over axial strain in i under "
                      "uniaxial stress in i (nu_yz = -S_zy / S_yy, nu_xz = -S_zx / S_xx, "
                      "nu_xy = -S_yx / S_xx)")
UNITS = {"length": "m", "displacement": "m", "stress": "Pa", "modulus": "Pa",
         "compliance": "1/Pa", "volume": "m^3", "force": "N", "moment": "N m", "time": "s",
         "poisson_ratio": "1", "density": "kg/m^3"}
HASH_OF = "sha256 of the float64 little-endian bytes of /particles/centers then /particles/radii"
HEADER_KEYS = ("schema_version", "command", "amfe_version", "input", "material", "box",
               "units", "counts", "poisson_convention", "S_unit", "C_unit", "voigt_order")


def bed_sha256(centers, radii):
    """Content hash (hex) of a bed: float64 LE centres (N, 3) then radii (N,).

    Not the file's hash: an HDF5 file's bytes change with its attributes and
    layout while the particles stay the same.
    """
    h = hashlib.sha256(np.ascontiguousarray(centers, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(radii, dtype="<f8").tobytes())
    return h.hexdigest()


def header(command, centers, radii, material, *, input_path=None):
    """The header of a result of ``command`` on the bed (centers, radii).

    Parameters
    ----------
    command : {"homogenize", "predict"}
    centers : ndarray (N, 3) [m]; radii : ndarray (N,) [m]
        The input bed.
    material : dict
        The material record: E [Pa], nu, psi and ``source`` ("bed file",
        "default (steel)", "command line", "argument", or a mix such as
        "command line (E); bed file (nu, psi)"), as
        :func:`amfe.model.material.resolve_material` gives it.
    input_path : str, optional
        The bed file (None: the bed came as arrays).

    Returns
    -------
    dict
        Keys :data:`HEADER_KEYS`; ``counts`` holds ``particles_input`` only.
    """
    centers = np.asarray(centers, dtype=float)
    lo, hi = centers.min(axis=0), centers.max(axis=0)
    return {"schema_version": SCHEMA_VERSION, "command": command, "amfe_version": __version__,
            "input": {"path": None if input_path is None else str(input_path),
                      "sha256": bed_sha256(centers, radii), "hash_of": HASH_OF},
            "material": {k: (v if k == "source" else float(v)) for k, v in material.items()},
            "box": {"min": lo.tolist(), "max": hi.tolist(), "size": (hi - lo).tolist(),
                    "of": "centres of the input particles"},
            "units": dict(UNITS), "counts": {"particles_input": int(len(centers))},
            "poisson_convention": POISSON_CONVENTION, "S_unit": "1/Pa", "C_unit": "Pa",
            "voigt_order": list(CASE_NAMES)}


def describe_input(result, input_path):
    """Fill in what only the caller knows: the bed file's path."""
    result["input"]["path"] = None if input_path is None else str(input_path)


def homogenize_header(frame, centers, radii, material):
    """:func:`header` of a homogenization, with the kept counts of ``frame``.

    ``bonds_input`` adds the bonds among the removed particles (a bond lies in
    the kept component iff one of its ends does), found at the frame's scale
    as :func:`amfe.model.frame.build_frame` found them.
    """
    out = header("homogenize", centers, radii, material)
    removed = np.ones(len(radii), bool)
    removed[frame.kept] = False
    n_lost = 0
    if removed.sum() > 1:
        scale = frame.length_scale
        n_lost = find_pairs((np.asarray(centers)[removed] - frame.origin) / scale,
                            np.asarray(radii)[removed] / scale)[0].size
    out["counts"].update(particles_kept=int(frame.n_particles),
                         bonds_input=int(len(frame.bonds) + n_lost),
                         bonds_kept=int(len(frame.bonds)))
    return out


def predict_block(out):
    """``amfe predict``'s own block (model, spread, flags) from its output dict.

    The flags come from ``flag_reasons`` ("spread", "fill", "non-finite") when
    the output has them, else from the spread score and the fill range.
    """
    fill_range, threshold, score = out.get("fill_range"), out.get("threshold"), out["spread_score"]
    reasons = out.get("flag_reasons")
    if reasons is None:
        reasons = (["spread"] if threshold is not None and out["members"] > 1
                   and score is not None and score > threshold else []) + \
                  (["fill"] if fill_range is not None
                   and not fill_range[0] <= out["fill"] <= fill_range[1] else [])
    return {"model": {"path": out["model"], "arch": out["arch"], "members": out["members"],
                      "inputs": list(out.get("inputs", ["fill"]))},
            "spread": {"relative": out["spread"], "score": score, "threshold": threshold},
            "flags": {"flagged": bool(out["flagged"]), "spread": "spread" in reasons,
                      "fill": "fill" in reasons, "non_finite": "non-finite" in reasons,
                      "interval": "interval" in reasons, "risk": "risk" in reasons,
                      "uncalibrated": "uncalibrated" in reasons,
                      "reasons": list(reasons), "fill_value": out["fill"],
                      "fill_range": fill_range},
            "source": out["source"]}


def load_schema():
    """The JSON Schema (draft 2020-12) of amfe's results, shipped in this package, with the
    boundary conditions' names read from the table (:mod:`amfe.model.conditions`): a
    result's ``bc`` is a registered condition, and ``--bc all`` holds those it solves."""
    schema = json.loads(resources.files("amfe.io").joinpath(SCHEMA_FILE).read_text())
    _name_conditions(schema)
    return schema


def _name_conditions(node):
    """Set, in place, every ``bc`` enum to the registered names and every ``conditions``
    object's names to those ``--bc all`` solves (the finite ones required)."""
    if isinstance(node, list):
        for item in node:
            _name_conditions(item)
        return
    if not isinstance(node, dict):
        return
    if isinstance(node.get("bc"), dict) and "enum" in node["bc"]:
        node["bc"]["enum"] = list(condition_names())
    group = node.get("conditions")
    if isinstance(group, dict) and "propertyNames" in group:
        group["propertyNames"]["enum"] = [n for n, c in CONDITIONS.items() if c.in_all]
        group["required"] = [n for n, c in CONDITIONS.items() if c.in_all and not c.periodic]
    for value in node.values():
        _name_conditions(value)


def validate(result):
    """Check a result dict against :func:`load_schema`; AmfeError names the first problem.

    Needs ``jsonschema`` (``pip install amfe[test]``).
    """
    try:
        import jsonschema  # noqa: PLC0415 (optional: the test extra)
    except ImportError:
        raise AmfeError("validating a result needs jsonschema: pip install jsonschema") from None
    validator = jsonschema.Draft202012Validator(load_schema())
    error = jsonschema.exceptions.best_match(validator.iter_errors(result))
    if error is not None:
        where = "/".join(str(p) for p in error.absolute_path) or "(top level)"
        raise AmfeError(f"the result does not follow the schema at {where}: {error.message}")
