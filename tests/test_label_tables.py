"""The committed label tables (labels/, issue 32): each data set's shards join, and
docs/datasets.md lists every one.

A shard that does not join (a gap, an overlap, another method or imaging among
a seed's shards) would make `amfe dataset --from-labels` refuse the tables on
a fresh clone; this catches it before it lands. No bed is regenerated here
(tests/test_labels.py rebuilds tables bit for bit).
"""
import collections
import json
import pathlib
import re

import pytest

from amfe.dataset.labels import MAX_TABLE_BYTES, read_tables

ROOT = pathlib.Path(__file__).resolve().parent.parent
NAME = re.compile(r"^(\w+)_seed(\d+)_labels_(\d{8})-(\d{8})\.h5$")


def groups():
    by = collections.defaultdict(list)
    for path in sorted((ROOT / "labels").glob("*labels*.h5")):
        m = NAME.match(path.name)
        assert m, f"{path.name} is not named SCALE_seedS_labels_FIRST-END.h5"
        by[(m.group(1), int(m.group(2)))].append(path)
    return dict(by)


def test_there_are_tables():
    assert ("small", 3) in groups() and ("paper", 22) in groups()


@pytest.mark.parametrize("key", sorted(groups()), ids=lambda k: f"{k[0]}-seed{k[1]}")
def test_the_shards_of_a_data_set_join(key):
    paths = groups()[key]
    table = read_tables(paths)   # refuses gaps, overlaps, mixed methods, rules or imaging
    scale, seed = key
    if scale.endswith("_continuum"):   # continuum-spring labels, named apart (issue 47)
        scale = scale.removesuffix("_continuum")
        assert json.loads(table["attrs"]["springs"])["name"] == "continuum"
    else:
        assert table["attrs"].get("springs") is None
    assert table["attrs"]["scale"] == scale and table["attrs"]["dataset_seed"] == seed
    ends = [tuple(int(x) for x in NAME.match(p.name).group(3, 4)) for p in paths]
    assert ends[0][0] == 0 and all(a[1] == b[0] for a, b in zip(ends, ends[1:]))
    assert ends[-1][1] == table["index"].shape[0]
    assert all(p.stat().st_size <= MAX_TABLE_BYTES for p in paths)


def test_docs_list_every_table():
    text = (ROOT / "docs" / "datasets.md").read_text()
    missing = [p.name for ps in groups().values() for p in ps if f"`{p.name}`" not in text]
    assert not missing, f"docs/datasets.md does not list {missing}"
