"""run/train/join_datasets.py and split_dataset.py: held-out sets of one kind joined record after
record, others refused; a split joined again gives the records back."""

import h5py
import numpy as np
from test_training import TINY_ATTRS, write_synthetic

from run.train import join_datasets, split_dataset


def _set(path, n, seed, **attrs):
    write_synthetic(path, n=n, shape=(1, 5, 5), attrs={**TINY_ATTRS, **attrs}, seed=seed,
                    failed=(1,))
    with h5py.File(path, "a") as f:
        f.attrs["seed"] = seed
    return path


def test_join_concatenates_every_record_dataset_and_keeps_the_bed_seeds(tmp_path):
    a, b = _set(str(tmp_path / "a.h5"), 7, 11), _set(str(tmp_path / "b.h5"), 5, 12)
    out = str(tmp_path / "j.h5")
    assert join_datasets.main([a, b, "-o", out]) == 0
    with h5py.File(a) as fa, h5py.File(b) as fb, h5py.File(out) as g:
        for name in ("images", "labels", "status", "index"):
            np.testing.assert_array_equal(g[name][()], np.concatenate([fa[name][()],
                                                                       fb[name][()]]))
        assert g.attrs["count"] == 12 and list(g.attrs["joined_seeds"]) == [11, 12]
        assert "seed" not in g.attrs and g.attrs["scale"] == "tiny"


def test_join_refuses_sets_of_another_kind_and_writes_nothing(tmp_path, capsys):
    a = _set(str(tmp_path / "a.h5"), 6, 1)
    b = _set(str(tmp_path / "b.h5"), 6, 2, bed_size=[0.3e-3, 0.3e-3, 0.1e-3])
    out = tmp_path / "j.h5"
    assert join_datasets.main([a, b, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "bed_size" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5", "b.h5"]   # no file, no tmp


def test_a_joined_file_is_refused_as_an_input_in_one_line(tmp_path, capsys):
    a, b = _set(str(tmp_path / "a.h5"), 4, 1), _set(str(tmp_path / "b.h5"), 4, 2)
    joined = str(tmp_path / "j.h5")
    assert join_datasets.main([a, b, "-o", joined]) == 0
    capsys.readouterr()
    assert join_datasets.main([joined, a, "-o", str(tmp_path / "k.h5")]) == 2
    err = capsys.readouterr().err
    assert "no /status or no seed attribute" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "k.h5").exists()


def test_a_split_joined_again_gives_the_records_back(tmp_path):
    a = _set(str(tmp_path / "a.h5"), 9, 5)
    parts = [str(tmp_path / "p0.h5"), str(tmp_path / "p1.h5")]
    assert split_dataset.main([a, "0", "4", "-o", parts[0]]) == 0
    assert split_dataset.main([a, "4", "9", "-o", parts[1]]) == 0
    with h5py.File(parts[1]) as f:
        assert f.attrs["split_first"] == 4 and f.attrs["count"] == 5 and f.attrs["seed"] == 5
    out = str(tmp_path / "j.h5")
    assert join_datasets.main(parts + ["-o", out]) == 0
    with h5py.File(a) as fa, h5py.File(out) as g:
        for name in ("images", "labels", "status", "index", "seed", "density"):
            np.testing.assert_array_equal(g[name][()], fa[name][()])
        assert list(g.attrs["joined_counts"]) == [4, 5] and "split_of" not in g.attrs
