"""Which shipped model predicts a bed: one network per bed size (issue 34).

The shipped multi-scale net pools its maps globally, so its weights read an
image of any in-plane size; the label, though, depends on the bed's size as
well as on its image (KUBC's boundary layer is a smaller share of a larger
bed), so each size the package predicts has its own fine-tuned checkpoint in
amfe/models/, named for its scale (amfe.model.scales), with its own
calibrated intervals. A bed is matched by its imaged in-plane size: the
recorded size cut to whole cells (amfe.training.anysize.whole_cells); a bed
file without a recorded size is imaged in the small box, as before.
"""
from pathlib import Path

import amfe.version
from amfe.errors import AmfeError
from amfe.model.scales import get_scale
from amfe.training.anysize import whole_cells

#: scale name -> checkpoint file in amfe/models/ (docs/model_card.md, docs/surrogate.md)
SHIPPED = {"small": "multiscale_small.pt", "medium": "multiscale_medium.pt",
           "paper": "multiscale_paper.pt"}
#: scale name -> a shipped full-stiffness model (21 Cholesky outputs: C and all nine
#: constants, amfe.training.stiffness_predict), chosen by ``amfe predict --stiffness``
STIFFNESS = {"small": "stiffness_small.pt", "medium": "stiffness_medium.pt",
             "paper": "stiffness_paper.pt"}


def models_dir():
    return Path(amfe.version.__file__).resolve().parent / "models"


def shipped_sizes(stiffness=False):
    """{(Lx, Ly) in whole cells: (scale name, path)} of the shipped checkpoints present
    (the full-stiffness ones with ``stiffness``)."""
    out = {}
    for name, file in (STIFFNESS if stiffness else SHIPPED).items():
        path = models_dir() / file
        if path.is_file():
            sc = get_scale(name)
            out[(whole_cells(sc.size[0], sc.cell[0]), whole_cells(sc.size[1], sc.cell[1]))] = \
                (name, path)
    return out


def shipped_model_for(bed, stiffness=False):
    """The path of the shipped checkpoint for ``bed``'s imaged size (a full-stiffness one with
    ``stiffness``); AmfeError naming the sizes there are when none fits (give --model, or
    solve the bed)."""
    table = STIFFNESS if stiffness else SHIPPED
    sizes = shipped_sizes(stiffness)
    size = bed.attrs.get("size") if hasattr(bed, "attrs") else None
    if size is None:   # imaged in the small box (training/predict.py, _image_size)
        size = get_scale("small").size
    cell = get_scale("small").cell
    try:
        key = (whole_cells(float(size[0]), cell[0]), whole_cells(float(size[1]), cell[1]))
    except (TypeError, ValueError, IndexError):   # malformed: the small model says so
        return models_dir() / table["small"]
    if key not in sizes:
        have = ", ".join(f"{nx * cell[0] * 1e3:g} x {ny * cell[1] * 1e3:g} mm ({name})"
                         for (nx, ny), (name, _) in sorted(sizes.items()))
        kind = "full-stiffness model" if stiffness else "model"
        raise AmfeError(f"no shipped {kind} for a {key[0] * cell[0] * 1e3:g} x "
                        f"{key[1] * cell[1] * 1e3:g} mm bed (shipped: {have}); give --model "
                        "MODEL.pt fine-tuned on that size, or solve it with amfe homogenize")
    return sizes[key][1]
