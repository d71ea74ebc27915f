"""The collection of the load-case files: ``cases.pvd`` and its sidecar ``cases.json``.

``cases.pvd`` is the only VTK XML amfe writes itself (the case files are
written by meshio, :mod:`amfe.io.vtu`): one ``DataSet`` per case, timestep =
case index, ``name`` = case name. ParaView ignores ``name`` and shows "Time: k".

meshio 5.3.5 writes no VTU field data, so what a case file cannot carry (its
label, macro-strain, warp factor, the units, the boundary condition, ...) is
in ``cases.json`` beside it, which ``amfe view`` and the ParaView script read::

    {"amfe_version": ..., "bc": ..., "units": {array: unit}, "descriptions":
     {array: text}, "end_convention": ..., "per_unit_strain": ...,
     "bonds_not_drawn": int, <the caller's field_data>,
     "cases": [{"file": "case_xx.vtu", "case_name": "xx", "case_label": ...,
                "macro_strain": [9 values, row-major], "macro_strain_voigt": [6],
                "warp_factor": float}, ...]}

(SUBC: ``macro_stress_Pa`` [9] instead of the two strain keys.)
"""
import json
import os
import xml.etree.ElementTree as ET
from xml.sax.saxutils import quoteattr

from amfe.errors import AmfeError

PVD_NAME = "cases.pvd"
SIDECAR_NAME = "cases.json"


def pvd_text(files, names):
    """The ``.pvd`` listing ``files`` (names relative to it) as cases ``names``, in order."""
    lines = ['<?xml version="1.0"?>',
             f"<!-- amfe load cases: timestep k = load case k; ParaView shows 'Time: k'. "
             f"Labels, macro-strains, warp factors and units: {SIDECAR_NAME} beside this "
             "file. SI units, per unit macro-strain -->",
             '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
             "  <Collection>"]
    for k, (f, nm) in enumerate(zip(files, names)):
        lines.append(f'    <DataSet timestep="{k}" group="" part="0" file={quoteattr(f)} '
                     f'name={quoteattr(nm)}/>')
    lines += ["  </Collection>", "</VTKFile>", ""]
    return "\n".join(lines)


def read_collection(path):
    """The cases of a ``.pvd``: ``[(name, absolute path of its file), ...]`` in order.

    Raises AmfeError for a file that is not a readable collection.
    """
    path = os.fspath(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise AmfeError(f"cannot read the collection {path}: {exc}") from None
    base = os.path.dirname(os.path.abspath(path))
    return [(ds.get("name") or f"t{ds.get('timestep')}", os.path.join(base, ds.get("file", "")))
            for ds in root.iter("DataSet")]


def read_sidecar(directory):
    """The ``cases.json`` of ``directory`` as a dict, or None when there is none.

    Raises AmfeError when it exists but is not a JSON object with a ``cases`` list.
    """
    path = os.path.join(os.fspath(directory), SIDECAR_NAME)
    if not os.path.isfile(path):
        return None
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError) as exc:
        raise AmfeError(f"cannot read {path}: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("cases"), list):
        raise AmfeError(f"{path}: not the {SIDECAR_NAME} of 'amfe homogenize --vtu'")
    return data


def case_fields(path):
    """What ``cases.json`` says about the case file ``path``: the common keys and its own.

    Returns
    -------
    dict
        ``{}`` when the directory has no ``cases.json`` or it does not list the file.
    """
    path = os.path.abspath(os.fspath(path))
    data = read_sidecar(os.path.dirname(path))
    if data is None:
        return {}
    mine = [c for c in data["cases"] if isinstance(c, dict)
            and c.get("file") == os.path.basename(path)]
    if not mine:
        return {}
    common = {k: v for k, v in data.items() if k != "cases"}
    return {**common, **mine[0]}
