"""Which shipped model predicts a bed: one network per bed size (issue 34).

The shipped multi-scale net pools its maps globally, so its weights read an
image of any in-plane size; the label, though, depends on the bed's size as
well as on its image (KUBC's boundary layer is a smaller share of a larger
bed), so each size the package predicts has its own fine-tuned checkpoint in
amfe/models/, named for its scale (amfe.model.scales), with its own
calibrated intervals. A bed is matched by its imaged in-plane size: the
recorded size cut to whole cells (amfe.training.imagebox.whole_cells); a bed
file without a recorded size by its spheres' bounding box cut the same way
(issue 46; the record's notes say so).
"""
from pathlib import Path

import numpy as np

import amfe.version
from amfe.errors import AmfeError
from amfe.model.scales import get_scale
from amfe.training.imagebox import whole_cells

#: scale name -> checkpoint file in amfe/models/ (docs/model_card.md, docs/surrogate.md)
SHIPPED = {"small": "multiscale_small.pt", "medium": "multiscale_medium.pt",
           "paper": "multiscale_paper.pt"}
#: scale name -> a shipped full-stiffness model (21 Cholesky outputs: C and all nine
#: constants, amfe.training.stiffness_predict), chosen by ``amfe predict --stiffness``
STIFFNESS = {"small": "stiffness_small.pt", "medium": "stiffness_medium.pt",
             "paper": "stiffness_paper.pt"}
#: scale name -> a shipped model of labels solved with ``--springs continuum`` (issue 47;
#: docs/model_card_continuum.md), chosen by ``amfe predict --springs continuum``
CONTINUUM = {"small": "multiscale_small_continuum.pt"}


def model_table(stiffness=False, springs="paper"):
    """The shipped models' table (scale name -> file) for the kind asked for; AmfeError for a
    kind none is shipped of (a full-stiffness model of the continuum springs)."""
    if springs == "continuum":
        if stiffness:
            raise AmfeError("no shipped full-stiffness model for the continuum springs: "
                            "predict without --stiffness, or solve with amfe homogenize "
                            "--springs continuum (its JSON has C and the shear moduli)")
        return CONTINUUM
    return STIFFNESS if stiffness else SHIPPED


def models_dir():
    return Path(amfe.version.__file__).resolve().parent / "models"


def shipped_sizes(stiffness=False, springs="paper"):
    """{(Lx, Ly) in whole cells: (scale name, path)} of the shipped checkpoints present
    (the full-stiffness ones with ``stiffness``, the continuum springs' with ``springs``)."""
    out = {}
    for name, file in model_table(stiffness, springs).items():
        path = models_dir() / file
        if path.is_file():
            sc = get_scale(name)
            out[(whole_cells(sc.size[0], sc.cell[0]), whole_cells(sc.size[1], sc.cell[1]))] = \
                (name, path)
    return out


def unrecorded_size(bed, cell, height):
    """The size (x, y, z) [m] a bed file without a recorded size is imaged at: its spheres'
    bounding box from the origin (max of centre + radius) to the nearest whole ``cell`` in x
    and y (at least one; a generated 0.6 mm bed's spheres reach 0.595-0.601 mm, which are
    20 cells), and ``height``."""
    far = np.max(np.asarray(bed.centers) + np.asarray(bed.radii)[:, None], axis=0)
    return (max(1, round(far[0] / float(cell[0]))) * float(cell[0]),
            max(1, round(far[1] / float(cell[1]))) * float(cell[1]), float(height))


def shipped_model_for(bed, stiffness=False, springs="paper"):
    """The path of the shipped checkpoint for ``bed``'s imaged size (a full-stiffness one with
    ``stiffness``, one of continuum-spring labels with ``springs="continuum"``); AmfeError
    quoting the bed's own size and the sizes there are when none
    fits (give --model, or solve the bed). A bed without a recorded size is matched by its
    spheres' bounding box (:func:`unrecorded_size`)."""
    table = model_table(stiffness, springs)
    sizes = shipped_sizes(stiffness, springs)
    size = bed.attrs.get("size") if hasattr(bed, "attrs") else None
    small = get_scale("small")
    cell = small.cell
    how = ""
    try:
        if size is None:
            size, how = unrecorded_size(bed, cell, small.size[2]), " (its spheres' bounding box)"
        key = (whole_cells(float(size[0]), cell[0]), whole_cells(float(size[1]), cell[1]))
    except (TypeError, ValueError, IndexError):   # malformed: the small model says so
        return models_dir() / table["small"]
    if key not in sizes:
        have = ", ".join(f"{nx * cell[0] * 1e3:g} x {ny * cell[1] * 1e3:g} mm ({name})"
                         for (nx, ny), (name, _) in sorted(sizes.items())) or "none installed"
        kind = ("full-stiffness model" if stiffness else
                "continuum-spring model" if springs == "continuum" else "model")
        raise AmfeError(f"no shipped {kind} for a {float(size[0]) * 1e3:g} x "
                        f"{float(size[1]) * 1e3:g} mm bed{how} (shipped: {have}); give --model "
                        "MODEL.pt fine-tuned on that size, or solve it with amfe homogenize"
                        f"{' --springs continuum' if springs == 'continuum' else ''} "
                        "(or --fallback)")
    return sizes[key][1]
