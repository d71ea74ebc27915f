"""Bed files: round trip, atomic writes, and a clear error for each malformed file."""

import h5py
import numpy as np
import pytest

import amfe.io.bedfile as bedio
from amfe.errors import AmfeError
from amfe.io.bedfile import read_bed, write_bed
from amfe.model.bed import Bed, generate_bed


@pytest.fixture(scope="module")
def bed():
    return generate_bed((120e-6, 120e-6, 80e-6), seed=5)


def test_round_trip(tmp_path, bed):
    path = tmp_path / "bed.h5"
    write_bed(path, bed)
    back = read_bed(path)
    assert np.array_equal(back.centers, bed.centers)
    assert np.array_equal(back.radii, bed.radii)
    assert back.centers.dtype == np.float64 and back.radii.dtype == np.float64
    assert back.attrs == bed.attrs
    assert type(back.attrs["seed"]) is int and type(back.attrs["r0"]) is float
    assert back.attrs["size"] == bed.attrs["size"]
    # The documented layout, read with plain h5py.
    with h5py.File(path, "r") as f:
        assert f["particles/centers"].shape == (bed.n, 3)
        assert f["particles/centers"].dtype == np.float64
        assert f["particles/radii"].shape == (bed.n,)
        assert f["particles/radii"].attrs["units"] == "m"
        assert f.attrs["generator"] == "amfe.hcp"
    assert [p.name for p in tmp_path.iterdir()] == ["bed.h5"]  # no temporary left


def test_round_trip_attribute_types(tmp_path):
    attrs = {"s": "text", "b": True, "i": 3, "f": 2.5, "npf": np.float64(1.25),
             "npi": np.int32(-4), "lst": [1.0, 2.0, 3.0], "arr": np.arange(4), "tup": (1, 2)}
    b = Bed(np.array([[0.0, 0, 0], [1e-5, 0, 0]]), np.array([6e-6, 6e-6]), attrs)
    write_bed(tmp_path / "a.h5", b)
    back = read_bed(tmp_path / "a.h5").attrs
    assert back == {"s": "text", "b": True, "i": 3, "f": 2.5, "npf": 1.25, "npi": -4,
                    "lst": [1.0, 2.0, 3.0], "arr": [0, 1, 2, 3], "tup": [1, 2]}
    assert type(back["b"]) is bool


@pytest.mark.parametrize("value", [None, {"a": 1}, ["x", "y"], object()])
def test_unsupported_attribute_is_an_error_and_writes_nothing(tmp_path, value):
    b = Bed([[0.0, 0, 0]], [1e-5], {"bad": value})
    with pytest.raises(AmfeError, match="'bad'"):
        write_bed(tmp_path / "a.h5", b)
    assert list(tmp_path.iterdir()) == []


def test_failure_mid_write_leaves_no_file(tmp_path, bed, monkeypatch):
    def boom(self, name, value):
        raise RuntimeError("disk full (simulated)")
    monkeypatch.setattr(h5py.AttributeManager, "__setitem__", boom)
    with pytest.raises(RuntimeError, match="simulated"):
        write_bed(tmp_path / "bed.h5", bed)
    assert list(tmp_path.iterdir()) == []


def test_failure_keeps_the_previous_file(tmp_path, bed, monkeypatch):
    path = tmp_path / "bed.h5"
    write_bed(path, bed)
    before = path.read_bytes()
    other = generate_bed((120e-6, 120e-6, 80e-6), seed=6)

    def fail_replace(src, dst):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(bedio.os, "replace", fail_replace)
    with pytest.raises(AmfeError, match="(?i)no space left"):
        write_bed(path, other)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["bed.h5"]


def test_write_into_missing_directory(tmp_path, bed):
    with pytest.raises(AmfeError, match="does not exist"):
        write_bed(tmp_path / "no" / "bed.h5", bed)


def test_foreign_file_is_accepted(tmp_path):
    """Another tool's file: float32 data, no attributes, extra content."""
    path = tmp_path / "foreign.h5"
    with h5py.File(path, "w") as f:
        f["particles/centers"] = np.array([[0, 0, 0], [2e-5, 0, 0]], dtype=np.float32)
        f["particles/radii"] = np.array([1.1e-5, 1.1e-5], dtype=np.float32)
        f["other/thing"] = np.arange(3)
    b = read_bed(path)
    assert b.centers.dtype == np.float64 and b.n == 2 and b.attrs == {}
    assert b.radii[0] == pytest.approx(1.1e-5, rel=1e-7)


def _write(path, centers=None, radii=None, skip=()):
    centers = np.array([[0, 0, 0], [2e-5, 0, 0]], float) if centers is None else centers
    radii = np.array([1.1e-5, 1.1e-5]) if radii is None else radii
    with h5py.File(path, "w") as f:
        if "centers" not in skip:
            f["particles/centers"] = centers
        if "radii" not in skip:
            f["particles/radii"] = radii
    return path


@pytest.mark.parametrize("kw, match", [
    ({"skip": ("radii",)}, "no /particles/radii dataset"),
    ({"skip": ("centers",)}, "no /particles/centers dataset"),
    ({"skip": ("centers", "radii")}, "no /particles/centers"),
    ({"centers": np.zeros((2, 2))}, r"shape \(N, 3\)"),
    ({"centers": np.zeros((2, 3, 1))}, r"shape \(N, 3\)"),
    ({"radii": np.ones(3) * 1e-5}, r"radii must have shape \(2,\)"),
    ({"radii": np.ones((2, 1)) * 1e-5}, r"radii must have shape \(2,\)"),
    ({"centers": np.array([[0, 0, 0], [np.nan, 0, 0]])}, "non-finite centres: particles 1"),
    ({"centers": np.array([[0, 0, 0], [np.inf, 0, 0]])}, "non-finite centres"),
    ({"radii": np.array([1e-5, -1e-5])}, "non-positive radii: 1"),
    ({"radii": np.array([1e-5, 0.0])}, "non-positive radii"),
    ({"radii": np.array([1e-5, np.nan])}, "non-finite or non-positive radii"),
    ({"radii": np.array([b"a", b"b"])}, "real numbers"),
    ({"radii": np.array([1e-5 + 0j, 1e-5])}, "real numbers"),
    ({"centers": np.zeros((0, 3)), "radii": np.zeros(0)}, "no particles"),
])
def test_malformed_files(tmp_path, kw, match):
    path = _write(tmp_path / "bad.h5", **kw)
    with pytest.raises(AmfeError, match=match) as exc:
        read_bed(path)
    assert "bad.h5" in str(exc.value)


def test_group_instead_of_dataset(tmp_path):
    path = tmp_path / "g.h5"
    with h5py.File(path, "w") as f:
        f.create_group("particles/centers")
        f["particles/radii"] = np.ones(2)
    with pytest.raises(AmfeError, match="must be a dataset"):
        read_bed(path)


def test_missing_file(tmp_path):
    with pytest.raises(AmfeError, match="does not exist"):
        read_bed(tmp_path / "nope.h5")


def test_not_hdf5(tmp_path):
    path = tmp_path / "bed.h5"
    path.write_text("centers,radii\n0,1\n")
    with pytest.raises(AmfeError, match="not an HDF5 file"):
        read_bed(path)
    with pytest.raises(AmfeError, match="directory"):
        read_bed(tmp_path)


def test_a_bed_with_flipped_bytes_is_an_error_or_the_same_bed(tmp_path, bed):
    """64 flipped bytes (issue 31) gave `RuntimeError: Unable to get link info`, KeyError,
    ValueError or TypeError tracebacks from h5py. Now every damaged file is one AmfeError, or,
    where only unused bytes or values were hit, a bed that passes the checks."""
    path = tmp_path / "bed.h5"
    write_bed(path, Bed(bed.centers[:60], bed.radii[:60]))
    raw = path.read_bytes()
    errors = 0
    for seed in range(120):
        damaged = bytearray(raw)
        for k in np.random.default_rng(seed).choice(len(raw), 64, replace=False):
            damaged[k] ^= 0xFF
        path.write_bytes(damaged)
        try:
            back = read_bed(path)
        except AmfeError as exc:
            errors += 1
            assert str(path) in str(exc)
            continue
        assert back.centers.shape == (60, 3)
    assert errors >= 100   # most of the file is metadata: nearly every flip is detected


def test_external_links_to_a_missing_file(tmp_path):
    """HDF5 external links to a file that is gone gave a KeyError traceback."""
    path = tmp_path / "linked.h5"
    with h5py.File(path, "w") as f:
        f["particles/centers"] = h5py.ExternalLink(str(tmp_path / "gone.h5"), "/c")
        f["particles/radii"] = h5py.ExternalLink(str(tmp_path / "gone.h5"), "/r")
    with pytest.raises(AmfeError, match=r"linked.h5: it is damaged or links to a file that is "
                                        r"missing \(.*gone.h5"):
        read_bed(path)
