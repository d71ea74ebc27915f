"""`amfe dataset --prefix-of`: the first records of a data set still being made.

Record k is a pure function of (seed, k), so the first N records of a larger
run must equal, bit for bit, what `amfe dataset --count N` makes directly; and
the run's part files must be left exactly as they were.
"""
import os

import numpy as np
import pytest
from test_dataset import ROW_KEYS, read_rows
from test_dataset_faults import tree

from amfe.cli import main
from amfe.dataset.parts import part_path, parts_dir, run_params, write_params_json, write_part
from amfe.dataset.plan import prepare
from amfe.dataset.prefix import write_prefix
from amfe.errors import AmfeError
from amfe.model.scales import PARAM_NAMES
from amfe.solvers.choice import GAMG_RTOL_AUTO

SEED, BIG, FIRST = 11, 7, 3
ARGS = ["--seed", str(SEED), "--scale", "tiny", "--no-progress", "--max-failed-share", "1"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A direct run of FIRST records, and a run of BIG records turned back into its parts."""
    d = tmp_path_factory.mktemp("prefix")
    direct, big = d / "direct.h5", d / "big.h5"
    assert main(["dataset", "-o", str(direct), "--count", str(FIRST), *ARGS]) == 0
    assert main(["dataset", "-o", str(big), "--count", str(BIG), *ARGS]) == 0
    rows = read_rows(big)
    running = d / "running.h5"       # as if still being made: parts, no merged file
    parts = parts_dir(running)
    os.makedirs(parts)
    params = run_params("tiny", SEED, BIG, GAMG_RTOL_AUTO, "auto")
    write_params_json(parts, params)
    for k in range(BIG):
        if k == FIRST + 1:           # a gap: records after it are not a prefix
            continue
        rec = {key: rows[key][k] for key in ROW_KEYS}
        rec.update(image=rec.pop("images"), bond_image=rec.pop("bond_images"),
                   seconds=np.zeros(3), solver="",
                   params=np.array([rows["params"][n][k] for n in PARAM_NAMES]))
        write_part(parts, rec, params)
    return direct, big, running


def test_prefix_equals_the_direct_run_and_leaves_the_parts(runs, tmp_path, capsys):
    direct, big, running = runs
    before = tree(parts_dir(running))
    out = tmp_path / "first.h5"
    assert main(["dataset", "--prefix-of", str(running), "-o", str(out),
                 "--count", str(FIRST)]) == 0
    assert f"records 0..{FIRST - 1}" in capsys.readouterr().out
    a, b = read_rows(out), read_rows(direct)
    for key in ROW_KEYS:
        assert np.array_equal(a[key], b[key], equal_nan=a[key].dtype.kind == "f"), key
    assert a["attrs"]["count"] == FIRST and a["attrs"]["seed"] == SEED
    assert "count 7" in a["attrs"]["prefix_of"]
    assert tree(parts_dir(running)) == before                     # the run is not disturbed
    # default count: every record finished in a row (0..FIRST; FIRST + 1 is missing)
    assert write_prefix(running, tmp_path / "all.h5") == FIRST + 1


def test_prefix_refuses_what_it_cannot_give(runs, tmp_path, capsys):
    direct, big, running = runs
    with pytest.raises(AmfeError, match=r"only records 0..3 .* in a row \(4\)"):
        write_prefix(running, tmp_path / "x.h5", FIRST + 2)
    with pytest.raises(AmfeError, match=rf"only records 0..{BIG - 1} of .* in a row \({BIG}\)"):
        write_prefix(big, tmp_path / "x.h5", BIG + 1)   # a finished file gives its own
    with pytest.raises(AmfeError, match="no data set being made"):
        write_prefix(tmp_path / "nothing.h5", tmp_path / "x.h5")
    assert main(["dataset", "--prefix-of", str(running)]) == 2
    assert "needs -o FIRST.h5" in capsys.readouterr().err
    os.remove(part_path(parts_dir(running), 0))     # last: the fixture's parts change here
    with pytest.raises(AmfeError, match="record 0 .* is not finished"):
        write_prefix(running, tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()


def _parts_of(rows, run, params, first):
    """Write records 0..first-1 of ``rows`` as the parts of an unfinished run ``run``."""
    parts = parts_dir(run)
    os.makedirs(parts)
    write_params_json(parts, params)
    for k in range(first):
        rec = {key: rows[key][k] for key in ROW_KEYS}
        rec.update(image=rec.pop("images"), bond_image=rec.pop("bond_images"),
                   seconds=np.zeros(3), solver="",
                   params=np.array([rows["params"][n][k] for n in PARAM_NAMES]))
        write_part(parts, rec, params)
    return parts


def test_a_run_grows_to_more_records_and_keeps_its_own(runs, tmp_path, capsys):
    """An unfinished run of FIRST records, rerun with --count BIG, equals the run of BIG."""
    direct, big, _ = runs
    run = tmp_path / "grown.h5"
    small = run_params("tiny", SEED, FIRST, GAMG_RTOL_AUTO, "auto")
    _parts_of(read_rows(direct), run, small, FIRST)
    assert main(["dataset", "-o", str(run), "--count", str(BIG), *ARGS]) == 0
    err = capsys.readouterr().err
    assert f"run of {FIRST} records" in err and f"grows to {BIG}" in err
    assert "refused" not in err                        # its parts were kept, not recomputed
    a, b = read_rows(run), read_rows(big)
    for key in ROW_KEYS:
        assert np.array_equal(a[key], b[key], equal_nan=a[key].dtype.kind == "f"), key
    assert a["attrs"]["count"] == BIG


def test_a_run_does_not_shrink_or_change_its_method(runs, tmp_path):
    direct, _, _ = runs
    run = tmp_path / "run.h5"
    params = run_params("tiny", SEED, FIRST, GAMG_RTOL_AUTO, "auto")
    parts = _parts_of(read_rows(direct), run, params, FIRST)
    before = tree(parts)
    with pytest.raises(AmfeError, match="--prefix-of"):
        prepare(run, run_params("tiny", SEED, FIRST - 1, GAMG_RTOL_AUTO, "auto"))
    with pytest.raises(AmfeError, match="other parameters"):
        prepare(run, run_params("tiny", SEED, BIG, 1e-9, "auto"))
    assert tree(parts) == before


def test_a_run_from_tables_keeps_its_parts_when_a_shard_joins_its_tables():
    """Only the count, and for two runs from label tables the tables and where solving
    starts, may change under a resumed run (a rebuilt record equals the solved one)."""
    from amfe.dataset.parts import same_but_count

    plain = run_params("small", 3, 100, GAMG_RTOL_AUTO, "auto")
    tables = {**plain, "from_labels": "a.h5", "label_rule_version": 2, "solved_from": 50}
    more = {**tables, "count": 200, "from_labels": "a.h5, b.h5", "solved_from": 80}
    assert same_but_count(plain, {**plain, "count": 200})
    assert same_but_count(tables, more) and same_but_count(more, tables)
    assert not same_but_count(plain, tables)                       # not across kinds of run
    assert not same_but_count(tables, {**more, "seed": 4})
    assert not same_but_count(tables, {**more, "label_rule_version": 1})
    assert not same_but_count({**plain, "from_labels": "a.h5"}, {**plain, "rtol": 1e-9,
                                                                 "from_labels": "a.h5"})
