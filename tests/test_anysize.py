"""The any-size network and the whole-cell imaging rule (docs/surrogate.md, "Any size")."""
import numpy as np
import pytest
import torch
from test_training import _tiny_bed

from amfe.errors import AmfeError
from amfe.training.anysize import AnySizeNet, predict_any_size, size_features
from amfe.training.fillcheck import COARSE_FILL_SHIFT, fill_shift
from amfe.training.imagebox import (
    bed_size,
    cropped_box,
    image_any_size,
    sample_spacing,
    sampling_note,
    whole_cells,
)

CELL = (30e-6, 30e-6)
PX = {"image_cell": CELL, "layer_thickness": 0.1e-3, "image_spacing": 2.5e-6}


@pytest.fixture(scope="module")
def tiny_bed(tmp_path_factory):
    from amfe.io.bedfile import read_bed
    return read_bed(_tiny_bed(tmp_path_factory.mktemp("anysize") / "bed.h5"))


def test_whole_cells_of_the_paper_sizes():
    assert [whole_cells(L, 30e-6) for L in (0.6e-3, 1.2e-3, 3e-3)] == [20, 40, 100]
    assert whole_cells(0.6149e-3, 30e-6) == 20   # 20.5 cells: the half cell is cropped
    assert cropped_box((0.62e-3, 0.9e-3, 0.3e-3), CELL) == pytest.approx((0.6e-3, 0.9e-3, 0.3e-3))
    with pytest.raises(AmfeError):
        whole_cells(20e-6, 30e-6)


def test_one_network_reads_paper_images_of_three_sizes():
    torch.manual_seed(0)
    net = AnySizeNet(3, channels=(4, 8), hidden=(16,)).eval()
    outs = []
    with torch.no_grad():
        for n, L in ((20, 0.6), (40, 1.2), (100, 3.0)):
            x = torch.full((1, 3, n, n), 0.5)
            outs.append(net(x, torch.tensor([[L, L]])))
    assert all(o.shape == (1, 21) and torch.isfinite(o).all() for o in outs)
    # The head reads the size: the same image said to be another size gives another output.
    with torch.no_grad():
        other = net(torch.full((1, 3, 20, 20), 0.5), torch.tensor([[1.2, 1.2]]))
    assert not torch.allclose(outs[0], other)


def test_crop_rule_reproduces_the_whole_cell_image(tiny_bed):
    """A bed recorded 5.5 cells wide is imaged as its 5 whole cells: the same image, the same
    prediction as the bed recorded at 5 cells; 6 whole cells give another image."""
    bed = tiny_bed
    size = tuple(bed.attrs["size"])
    assert whole_cells(size[0], CELL[0]) == 5
    whole, box = image_any_size(bed, size, CELL, 0.1e-3, 2.5e-6)
    wider = (size[0] + 15e-6, size[1] + 29e-6, size[2])
    cropped, box2 = image_any_size(bed, wider, CELL, 0.1e-3, 2.5e-6)
    np.testing.assert_array_equal(cropped, whole)
    assert box2 == pytest.approx(box)
    six, _ = image_any_size(bed, (size[0] + 30e-6, size[1], size[2]), CELL, 0.1e-3, 2.5e-6)
    assert six.shape[-1] == 6 and whole.shape[-1] == 5
    # A pad read as void would lower the last column's fill; the crop has no such column.
    assert whole[..., -1].mean() > 0


def test_any_size_prediction_on_two_sizes(tiny_bed):
    from amfe.model.bed import Bed
    torch.manual_seed(1)
    net = AnySizeNet(1, channels=(4, 8), hidden=(16,)).double()
    size = tuple(bed_size(tiny_bed, 1, 0.1e-3))
    wide = Bed(tiny_bed.centers, tiny_bed.radii,
               attrs={**tiny_bed.attrs, "size": (size[0] + 30e-6, size[1] + 60e-6, size[2])})
    off = Bed(tiny_bed.centers, tiny_bed.radii,
              attrs={**tiny_bed.attrs, "size": (size[0] + 14e-6, size[1] + 14e-6, size[2])})
    C, nine = predict_any_size(net, [tiny_bed, wide, off], PX, layers=1, scale=1e9, tta="flips")
    assert C.shape == (3, 6, 6) and nine.shape == (3, 9) and np.isfinite(nine).all()
    assert np.linalg.eigvalsh(C).min() > 0
    assert np.abs(C[1] - C[0]).max() > 1e-6 * np.abs(C[0]).max()   # the sizes differ
    np.testing.assert_allclose(C[2], C[0], rtol=1e-12)   # partial cells cropped: the same bed
    with pytest.raises(AmfeError, match="layers"):
        predict_any_size(net, [tiny_bed], PX, layers=3)


def test_size_features_are_millimetres():
    np.testing.assert_allclose(size_features([(0.6e-3, 1.2e-3, 0.3e-3)]).numpy(), [[0.6, 1.2]],
                               rtol=1e-6)


def test_large_beds_are_sampled_at_twice_the_spacing():
    """Over a million sample lines at the training's 2.5 um (12 a 0.03 mm cell side), a bed
    is sampled at 5 um: a 3 or 4 mm bed, not a 2 mm one nor the size rule's 2.5 mm bed cropped
    to 83 whole cells (996^2 lines); the record's note and the fill check follow."""
    cell, h = (30e-6, 30e-6), 2.5e-6
    for side, want in ((0.6e-3, h), (1.2e-3, h), (2e-3, h), (83 * 30e-6, h), (3e-3, 2 * h),
                       (4e-3, 2 * h), (84 * 30e-6, 2 * h)):
        box = (side, side, 0.3e-3)
        assert sample_spacing(box, cell, h) == want, side
        assert (sampling_note(box, cell, h) is None) == (want == h)
        assert fill_shift(box, cell, h) == (0.0 if want == h else COARSE_FILL_SHIFT)
    assert sample_spacing((6e-3, 0.15e-3, 0.3e-3), cell, h) == h    # a long strip: 144 000 lines
    assert "5 um" in sampling_note((3e-3, 3e-3, 0.3e-3), cell, h)
    # a model trained on another grid keeps its own spacing: the rule was measured on this one
    assert sample_spacing((4e-3, 4e-3, 0.3e-3), cell, 1.25e-6) == 1.25e-6
    assert sample_spacing((4e-3, 4e-3, 0.3e-3), (50e-6, 50e-6), h) == h
    assert fill_shift((4e-3, 4e-3, 0.3e-3), cell, 1.25e-6) == 0.0
