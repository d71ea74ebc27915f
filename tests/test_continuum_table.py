"""The committed continuum labels of issue 47 (labels/continuum/): each table's numbers are
what its ladders say and its beds are the plan's.

Checks against independent computations: the moduli extrapolated to H -> 0 are those that
amfe.model.extrapolate gives again from the table's own rungs; a bed regenerated from
(plan seed, k) has the table's particles, and the frame solved on it here gives the
table's frame constants; every fifth bed is held out; docs/datasets.md lists every table.
"""
import pathlib
import re

import h5py
import numpy as np
import pytest

from run.report.continuum_table import FORMAT, NAMES
from run.report.voxel_ladder import extrapolated

ROOT = pathlib.Path(__file__).resolve().parent.parent
TABLES = sorted((ROOT / "labels" / "continuum").glob("voxel_ladders_seed*_*-*.h5"))
NAME = re.compile(r"^voxel_ladders_seed(\d+)_(\d{5})-(\d{5})\.h5$")


def read(path):
    with h5py.File(path, "r") as f:
        return {k: f[k][()] for k in f}, dict(f.attrs)


def test_there_is_a_table_and_docs_list_every_one():
    assert TABLES
    text = (ROOT / "docs" / "datasets.md").read_text()
    for path in TABLES:
        assert NAME.match(path.name), path.name
        assert f"`{path.name}`" in text, f"docs/datasets.md does not list {path.name}"


@pytest.mark.parametrize("path", TABLES, ids=lambda p: p.name)
def test_the_extrapolated_moduli_are_those_of_the_tables_own_rungs(path):
    c, attrs = read(path)
    assert attrs["format"] == FORMAT and list(attrs["property_names"]) == list(NAMES)
    seed, first, end = map(int, NAME.match(path.name).groups())
    assert attrs["plan_seed"] == seed
    assert c["index"].tolist() == list(range(first, end))
    assert np.array_equal(c["held_out"], c["index"] % 5 == 4)
    names = [n.decode() if isinstance(n, bytes) else n for n in attrs["extrapolated_names"]]
    for i in np.flatnonzero(c["status"] == 0):
        levels = [{"voxel_size": h, "properties": dict(zip(NAMES, p))}
                  for h, p in zip(c["voxel_size"][i], c["properties"][i])]
        again = extrapolated(levels)
        np.testing.assert_allclose(c["extrapolated_value"][i],
                                   [again[k]["value"] for k in names], rtol=1e-12)
        np.testing.assert_allclose(c["extrapolated_error"][i],
                                   [again[k]["error"] for k in names], rtol=1e-12)
        # a finer rung resolves at least the necks a coarser one does
        assert np.all(np.diff(c["voxel_size"][i]) < 0)
        # the plan draws a rare sparse bed (0.05); the bounds catch unit and box errors
        assert np.all(c["solid_fraction"][i] > 0.02) and np.all(c["solid_fraction"][i] < 0.9)


def test_a_beds_frame_constants_are_those_of_the_bed_the_plan_makes():
    """Bed 0 of the first table, regenerated from its plan and solved here by the frame
    (KUBC on the bed's box, as the ladder ran it)."""
    import amfe
    from run.report.continuum_ladders import bed_of
    c, attrs = read(TABLES[0])
    k = int(c["index"][0])
    bed, record = bed_of(int(attrs["plan_seed"]), k)
    assert record["bed_seed"] == c["bed_seed"][0] and bed.n == c["n_particles"][0]
    res = amfe.homogenize(bed, bc="kubc")
    got = [res.properties[name] for name in NAMES]
    np.testing.assert_allclose(got, c["frame_properties"][0], rtol=1e-6)
