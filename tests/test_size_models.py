"""One network per bed size (issue 34): fine-tuning across sizes and the shipped model per bed."""
import numpy as np
import pytest
import torch
from test_training import SMALL_ATTRS, write_synthetic

from amfe.errors import AmfeError
from amfe.model.bed import Bed
from amfe.model.scales import bed_for, get_scale, record_seed
from amfe.training.checkpoint import save_checkpoint
from amfe.training.predict import Surrogate
from amfe.training.shipped import SHIPPED, models_dir, shipped_model_for
from amfe.training.train import TrainConfig, train_model

torch.set_num_threads(1)
QUIET = {"progress": False, "log": lambda line: None}
MEDIUM_ATTRS = dict(SMALL_ATTRS, scale="medium", bed_size=[1.2e-3, 1.2e-3, 0.3e-3])


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    d = tmp_path_factory.mktemp("sizes")
    small = str(write_synthetic(d / "small.h5", n=40, seed=0))
    medium = str(write_synthetic(d / "medium.h5", n=30, shape=(3, 40, 40), attrs=MEDIUM_ATTRS,
                                 seed=1, failed=()))
    ckpt = train_model(small, TrainConfig(arch="multiscale", arch_args={"width": 0.25}, epochs=1,
                                          batch_size=16, members=1, seed=0), **QUIET)
    path = d / "small.pt"
    save_checkpoint(path, ckpt)
    return {"path": str(path), "ckpt": ckpt, "small": small, "medium": medium, "dir": d}


def test_a_size_free_net_fine_tunes_on_another_bed_size(base):
    """A multi-scale net (global pooling) starts from its weights on 40 x 40 images of 1.2 mm
    beds: at a vanishing learning rate the tuned member reads them exactly as the small model
    does, and the new checkpoint is for the new size (shape and pixelation)."""
    from amfe.training.data import read_rows
    tuned = train_model(base["medium"], TrainConfig(epochs=1, batch_size=16, seed=0, lr=1e-12,
                                                    init=base["path"]), **QUIET)
    assert tuned["image_shape"] == [3, 40, 40]
    assert np.allclose(tuned["pixelation"]["bed_size"], MEDIUM_ATTRS["bed_size"])
    images, _ = read_rows(base["medium"])
    # the small model's checkpoint refuses a 40 x 40 image, so compare the networks directly
    from amfe.training.checkpoint import build_members
    x = torch.from_numpy(np.ascontiguousarray(images[:8]))
    with torch.no_grad():
        before = build_members(base["ckpt"])[0](x).numpy()
        after = build_members(tuned)[0](x).numpy()
    np.testing.assert_allclose(after, before, rtol=1e-5, atol=1e-6)
    assert np.abs(before).max() > 1e-3   # not two zero outputs


def test_a_fixed_size_net_still_refuses_another_bed_size(base, tmp_path):
    ckpt = train_model(base["small"], TrainConfig(arch="lenet5", epochs=1, batch_size=16,
                                                  members=1, seed=0), **QUIET)
    path = tmp_path / "lenet.pt"
    save_checkpoint(path, ckpt)
    with pytest.raises(AmfeError, match="shape 3x40x40"):
        train_model(base["medium"], TrainConfig(epochs=1, init=str(path)), **QUIET)


def test_the_shipped_model_is_chosen_by_the_beds_size():
    small = bed_for(get_scale("small"), record_seed(2, 0))
    assert shipped_model_for(small) == models_dir() / SHIPPED["small"]
    # a bed file without a recorded size is matched by its spheres' bounding box to the
    # nearest whole cells (issue 46): this bed's spheres stop short of 0.6 mm in y (19.8
    # cells), so it is read as 0.6 mm and gets the small model; one whose spheres reach
    # only 0.56 mm (18.7 cells) is read as 0.57 mm and refused, with the box it was read as
    bare = Bed(small.centers, small.radii, {})
    far = small.centers + small.radii[:, None]
    assert 19.5 < far[:, 1].max() / 30e-6 < 20
    assert shipped_model_for(bare) == models_dir() / SHIPPED["small"]
    cut = far[:, 1] < 0.56e-3
    short = Bed(small.centers[cut], small.radii[cut], {})
    n_y = round((small.centers[cut, 1] + small.radii[cut]).max() / 30e-6)
    with pytest.raises(AmfeError, match=rf"for a 0\.6 x {n_y * 0.03:g} "
                                        r"mm bed \(its spheres' bounding box\)"):
        shipped_model_for(short)
    # a size within a cell's rounding of 0.6 mm is 0.6 mm (whole cells)
    near = Bed(small.centers, small.radii, {"size": [0.6e-3 + 1e-12, 0.6e-3, 0.3e-3]})
    assert shipped_model_for(near) == models_dir() / SHIPPED["small"]
    odd = Bed(small.centers, small.radii, {"size": [0.9e-3, 0.9e-3, 0.3e-3]})
    with pytest.raises(AmfeError, match=r"no shipped model for a 0\.9 x 0\.9 mm bed.*0\.6 x 0\.6"):
        shipped_model_for(odd)


def test_the_shipped_medium_model_predicts_its_beds():
    """amfe/models/multiscale_medium.pt: the 1.2 mm beds' own network and intervals; three
    beds of the held-out seed against the PETSc solve (its test beds' mean errors are
    1.5-2.9 %, docs/model_card_medium.md)."""
    from helpers import homogenize_arrays

    from amfe.training.checkpoint import load_checkpoint
    from amfe.vocab import LABEL_NAMES
    path = models_dir() / SHIPPED["medium"]
    ck = load_checkpoint(path)
    assert ck["image_shape"] == [6, 40, 40] and ck["label_rule"] == 2
    assert list(ck["conformal"]["sizes"]) == ["1.2x1.2"]
    sc = get_scale("medium")
    sur = Surrogate.load(path)
    for k in range(3):
        bed = bed_for(sc, record_seed(12, k))
        assert shipped_model_for(bed) == path
        res = sur.predict_bed(bed)[0]["mean"][0]
        props = homogenize_arrays(bed.centers, bed.radii, bed.material(),
                                  size=bed.attrs["size"])["properties"]
        want = np.array([props[n] for n in LABEL_NAMES])
        assert np.abs(res / want - 1).max() < 0.15, (k, res, want)


def committed_labels(scale, seed, first=2):
    """The committed label table labels/{scale}_seed{seed}_labels_*.h5 (the PETSc solves), after
    checking that its records 0..first-1 are the beds bed_for regenerates from the seed."""
    import glob
    import os

    from amfe.dataset.labels import read_tables
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    table = read_tables(sorted(glob.glob(os.path.join(root, "labels",
                                                      f"{scale}_seed{seed}_labels_*.h5"))))
    for k in range(first):
        assert table["bed_seed"][k] == record_seed(seed, k)   # the label is this bed's
    return table


@pytest.mark.parametrize("scale, seed", [("small", 4), ("medium", 12), ("paper", 22)])
def test_the_shipped_stiffness_model_gives_the_nine_constants_of_held_out_beds(scale, seed):
    """amfe/models/stiffness_{small,medium,paper}.pt (`amfe predict --stiffness`): C SPD, all
    nine constants from it, against two held-out beds of seed 4 (0.6 mm), 12 (1.2 mm) or 22
    (3 mm; their committed labels' C, the PETSc solves)."""
    from amfe.model.averages import compliance_and_constants
    from amfe.training.shipped import STIFFNESS
    path = models_dir() / STIFFNESS[scale]
    table = committed_labels(scale, seed)
    sur = Surrogate.load(path)
    names = ("Ex", "Ey", "Ez", "nu_yz", "nu_xz", "nu_xy", "G_yz", "G_xz", "G_xy")
    for k in range(2):
        bed = bed_for(get_scale(scale), record_seed(seed, k))
        assert shipped_model_for(bed, stiffness=True) == path
        res = sur.predict_bed(bed)[0]
        C = np.asarray(res["stiffness"][0])
        assert np.allclose(C, C.T) and np.linalg.eigvalsh(C).min() > 0
        props = compliance_and_constants(C)[1]
        np.testing.assert_allclose(res["mean"][0], [props[n] for n in names[:6]], rtol=1e-6)
        want = compliance_and_constants(table["C"][k])[1]
        err = [abs(props[n] / want[n] - 1) for n in names]
        assert max(err) < 0.2, (k, dict(zip(names, err)))


def test_a_size_without_a_full_stiffness_model_is_refused_in_one_line():
    small = bed_for(get_scale("small"), record_seed(2, 0))
    odd = Bed(small.centers, small.radii, {"size": [0.9e-3, 0.9e-3, 0.3e-3]})
    with pytest.raises(AmfeError, match=r"no shipped full-stiffness model for a 0\.9 x 0\.9 mm"):
        shipped_model_for(odd, stiffness=True)


def test_the_shipped_paper_model_predicts_its_held_out_beds():
    """amfe/models/multiscale_paper.pt: the 3 mm beds' own network and intervals. Two beds of
    the held-out seed 22 against their committed labels (the PETSc solves of
    labels/paper_seed22_labels_*.h5; its 150 test beds' mean errors are in
    docs/model_card_paper.md)."""
    from amfe.model.averages import compliance_and_constants
    from amfe.training.checkpoint import load_checkpoint
    from amfe.vocab import LABEL_NAMES
    path = models_dir() / SHIPPED["paper"]
    ck = load_checkpoint(path)
    assert ck["image_shape"] == [6, 100, 100] and ck["label_rule"] == 2
    assert list(ck["conformal"]["sizes"]) == ["3x3"]
    table = committed_labels("paper", 22)
    sc = get_scale("paper")
    sur = Surrogate.load(path)
    for k in range(2):
        bed = bed_for(sc, record_seed(22, k))
        assert shipped_model_for(bed) == path
        got = sur.predict_bed(bed)[0]["mean"][0]
        props = compliance_and_constants(table["C"][k])[1]
        want = np.array([props[n] for n in LABEL_NAMES])
        assert np.abs(got / want - 1).max() < 0.15, (k, got, want)
