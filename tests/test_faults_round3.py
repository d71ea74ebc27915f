"""Issue 45, round three of the faults: a Bed owns its arrays (item 4), stray pieces do not
define the box (item 6, the one box rule of amfe.model.carrying), VTU sets own their
directory (item 7) and corrupt HDF5 chunks give one line (item 9). docs/hard_cases.md."""
import numpy as np
import pytest

from amfe.errors import AmfeError
from amfe.model.bed import Bed, generate_bed
from amfe.model.carrying import box_rule, stray_pieces, component_labels
from amfe.model.frame import build_frame

from helpers import homogenize_arrays


# --------------------------------------------------------------- item 4: a Bed's arrays
def test_bed_copies_and_locks_its_arrays():
    b = generate_bed(size=(110e-6, 110e-6, 100e-6), seed=1)
    x, r = np.array(b.centers), np.array(b.radii)
    bed = Bed(x, r)
    x[0, 0] = np.nan                      # written after the check: must not reach the bed
    r[1] = np.inf
    assert np.isfinite(bed.centers).all() and np.isfinite(bed.radii).all()
    assert bed.centers[0, 0] == b.centers[0, 0] and bed.radii[1] == b.radii[1]
    with pytest.raises(ValueError):
        bed.centers[0, 0] = np.nan
    with pytest.raises(ValueError):
        bed.radii[0] = -1.0
    assert build_frame(bed.centers, bed.radii).n_input == b.n


# --------------------------------------------------------------- item 6: strays and the box
def _issue_bed():
    """The issue's bed: a generated bed (100 particles, ~ the issue's 99) without its recorded
    size, plus a bonded tetrahedron of 4 strays one bed width away along x."""
    b = generate_bed(size=(110e-6, 110e-6, 100e-6), seed=1)
    x, r = b.centers, b.radii
    lo, hi = x.min(0), x.max(0)
    w = hi - lo
    R = r.mean()
    c = np.array([hi[0] + w[0], lo[1] + w[1] / 2, lo[2] + w[2] / 2])
    tet = np.array([[0, 0, 0], [1.8, 0, 0], [0.9, 1.56, 0], [0.9, 0.52, 1.47]]) * R
    return x, r, np.vstack([x, c + tet]), np.concatenate([r, np.full(4, R)])


def test_strays_one_bed_width_away_do_not_set_the_box():
    x, r, xs, rs = _issue_bed()
    fr = build_frame(xs, rs)
    assert fr.n_particles == x.shape[0] and fr.kept.max() < x.shape[0]   # strays removed
    assert fr.removed["particles"] == 4 and fr.box_source == "spheres' box"
    ref = build_frame(x, r)
    assert np.allclose(fr.size * fr.length_scale, ref.size * ref.length_scale, rtol=1e-12)
    alone = homogenize_arrays(x, r, solver="cholesky")
    both = homogenize_arrays(xs, rs, solver="cholesky")
    C0, C1 = np.array(alone["C"]), np.array(both["C"])
    assert np.abs(C1 - C0).max() <= 1e-10 * np.abs(C0).max()
    assert both["volume"] == pytest.approx(alone["volume"], rel=1e-12)
    assert any("4 particles" in w for w in both["warnings"])


def test_a_small_piece_inside_the_bed_is_no_stray_and_equal_blocks_are_none():
    x, r, xs, rs = _issue_bed()
    from amfe.model.bonds import find_pairs
    L = r.mean()
    labels = component_labels(xs.shape[0], *find_pairs(xs / L, rs / L))
    assert stray_pieces(xs / L, rs / L, labels).size == 1
    labels0 = component_labels(x.shape[0], *find_pairs(x / L, r / L))
    assert stray_pieces(x / L, r / L, labels0).size == 0
    # two equal blocks apart: neither is small, neither is a stray (both carry, as before)
    two = np.vstack([x, x + [3 * np.ptp(x[:, 0]), 0, 0]])
    labels2 = component_labels(two.shape[0], *find_pairs(two / L, np.tile(r, 2) / L))
    assert stray_pieces(two / L, np.tile(r, 2) / L, labels2).size == 0


def test_box_rule_sources_and_a_given_box():
    b = generate_bed(size=(110e-6, 110e-6, 100e-6), seed=1)
    x, r, size = b.centers, b.radii, b.attrs["size"]
    L, note, source = box_rule(x, r, size)
    assert source == "recorded size" and note is None and np.allclose(L, size)
    assert box_rule(x, r)[2] == "spheres' box"
    assert box_rule(x, r, [s / 2 for s in size])[2] == "spheres' box"
    given = np.array(size) * 1.1
    L, note, source = box_rule(x, r, size, given=given)
    assert source == "given box" and np.array_equal(L, given)
    with pytest.raises(AmfeError, match="given box .* does not hold the load-carrying centres"):
        box_rule(x, r, size, given=np.array(size) * 0.5)
    with pytest.raises(AmfeError, match="three positive lengths"):
        box_rule(x, r, given=[1e-4, -1, 1e-4])
    fr = build_frame(x, r, size=size, given_box=given)
    assert fr.box_source == "given box"
    assert fr.volume * fr.length_scale**3 == pytest.approx(np.prod(given), rel=1e-12)
    per = generate_bed(size=(110e-6, 110e-6, 100e-6), seed=1, periodic=True)
    assert build_frame(per.centers, per.radii, box=per.attrs["periodic"]).box_source \
        == "periodic box"


# --------------------------------------------------------------- item 9: damaged HDF5 chunks
def _compress(path, name, chunk_rows=4):
    import h5py
    with h5py.File(path, "a") as f:
        a = f[name][()]
        del f[name]
        f.create_dataset(name, data=a, chunks=(chunk_rows,) + a.shape[1:], compression="gzip",
                         shuffle=True)


def _corrupt_chunk(path, name, chunk=1):
    """Flip 16 bytes in the middle of compressed chunk ``chunk`` of /name: inflate() fails."""
    import h5py
    with h5py.File(path, "r") as f:
        info = f[name].id.get_chunk_info(chunk)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + info.size // 2)
        b = fh.read(16)
        fh.seek(info.byte_offset + info.size // 2)
        fh.write(bytes(x ^ 0xFF for x in b))


def _damaged_dataset(tmp_path, name="images"):
    from cli_fixtures import tiny_dataset
    p = tmp_path / "tiny.h5"
    tiny_dataset(p)
    _compress(p, name)
    _corrupt_chunk(p, name)
    return p


ONE_LINE = "cannot read data set .*\\(a damaged or truncated file\\); restore it from a copy"


def test_a_damaged_chunk_of_a_data_set_is_one_line_for_check_and_train(tmp_path):
    from cli_fixtures import run_main
    p = _damaged_dataset(tmp_path)
    code, out, err = run_main(["dataset", "--check", p])
    assert code == 2 and "inflate() failed" in err and str(p) in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    code, out, err = run_main(["train", p, "-o", tmp_path / "m.pt", "--quiet", "--epochs", "1"])
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "damaged or truncated file" in err and str(p) in err
    assert not (tmp_path / "m.pt").exists()


def test_check_reads_every_chunk_even_of_a_dataset_it_does_not_load(tmp_path):
    """A damaged chunk in an extra dataset (a group load_dataset does not read) is found."""
    import h5py
    from cli_fixtures import run_main, tiny_dataset
    p = tmp_path / "tiny.h5"
    tiny_dataset(p)
    code, _, err = run_main(["dataset", "--check", p])
    assert code == 1 and "damaged" not in err   # a synthetic file: layout problems, no damage
    with h5py.File(p, "a") as f:
        f.create_dataset("extra/notes", data=np.arange(4000.0), chunks=(500,),
                         compression="gzip")
    _corrupt_chunk(p, "extra/notes")
    code, _, err = run_main(["dataset", "--check", p])
    assert code == 2 and "damaged or truncated file" in err


def test_training_reads_of_a_damaged_data_set_are_amfe_errors(tmp_path):
    from training.data import BedDataset, read_rows
    p = _damaged_dataset(tmp_path)
    with pytest.raises(AmfeError, match=ONE_LINE):
        read_rows(p)
    ds = BedDataset(p)               # status and labels are sound: opening works
    with pytest.raises(AmfeError, match=ONE_LINE):
        [ds[k] for k in range(len(ds))]


def test_a_damaged_label_shard_is_one_line(tmp_path):
    import h5py
    from amfe.dataset.labels import IDENTITY, TABLE_FORMAT, read_tables
    p = tmp_path / "shard.h5"
    with h5py.File(p, "w") as f:
        f.attrs.update({k: 1 for k in IDENTITY})
        f.attrs["format"] = TABLE_FORMAT
        f.create_dataset("index", data=np.arange(4000), chunks=(500,), compression="gzip")
    _corrupt_chunk(p, "index")
    with pytest.raises(AmfeError, match="cannot read label table .*shard.h5: .*inflate.*"
                       "damaged or truncated file\\); export it again"):
        read_tables([p])
    from cli_fixtures import run_main
    code, _, err = run_main(["dataset", "--from-labels", p, "-o", tmp_path / "d.h5"])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "export it again" in err, err
