"""Upgrading older data-set files: the bond images of beds regenerated from their seeds."""
import os

import numpy as np

from amfe.dataset.bondimage import bond_image
from amfe.dataset.datacheck import check_dataset
from amfe.dataset.datafile import _image_dataset, missing_dataset
from amfe.dataset.lock import DatasetLock
from amfe.dataset.parts import STATUS_OK
from amfe.errors import AmfeError
from amfe.io.atomic import atomic_write_h5
from amfe.model.scales import bed_for, get_scale


def record_bond_image(bed, sc):
    """The bond image of a record's bed on its scale's grid (box [0, scale size])."""
    return bond_image(bed, cell=sc.cell, layer_thickness=sc.layer_thickness,
                      box=((0.0, 0.0, 0.0), sc.image_box))



def add_bond_images(path, progress=True):
    """Add ``/bond_images`` to a data-set file made before it existed; returns the record count.

    Each record's bed is regenerated from its seed (``bed_for(scale, seed)``,
    what ``amfe pack --scale S --seed SEED`` does) and imaged by
    :func:`amfe.dataset.bondimage.bond_image` on the file's grid; records whose bed
    cannot be made get zeros (they are failed records). The file is rewritten
    through a copy in memory, a temporary file and os.replace, so a kill leaves it as it was.
    About 0.05 s per `small` bed. AmfeError if the file already has bond
    images, is not a valid data set, or a bed no longer matches its image
    (generator changed since the file was made).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise AmfeError(missing_dataset(path))
    with DatasetLock(path):   # no `amfe dataset` may write the file meanwhile
        return _add_bond_images(path, progress)


def _add_bond_images(path, progress):

    problems, data, attrs = check_dataset(path)
    if problems:
        raise AmfeError(f"{path} is not a valid data set ({problems[0]}); see amfe dataset "
                        "--check")
    if "bond_images" in data:
        raise AmfeError(f"{path} already has /bond_images")
    sc = get_scale(attrs["scale"])
    M = data["index"].shape[0]
    out = np.zeros((M, *sc.image_shape), np.float32)
    bar = None
    if progress:
        from tqdm import tqdm  # noqa: PLC0415 (heavy or optional: loaded when used)
        bar = tqdm(total=M, desc="bond images", unit="bed", dynamic_ncols=True)
    for k in range(M):
        try:
            bed = bed_for(sc, int(data["seed"][k]))
        except AmfeError:
            bed = None
        if bed is not None:
            if bed.n != int(data["n_particles"][k]) and int(data["n_particles"][k]) >= 0:
                raise AmfeError(f"record {k} of {path}: its seed now makes a bed of {bed.n} "
                                f"particles, the file says {int(data['n_particles'][k])}; the "
                                "generator has changed since the file was made: remake it")
            try:
                out[k] = record_bond_image(bed, sc)
            except AmfeError:
                if int(data["status"][k]) == STATUS_OK:
                    raise
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()

    atomic_write_h5(path, lambda f: _image_dataset(f, "bond_images", M, sc.image_shape,
                                                   data=out), base=path)
    return M
