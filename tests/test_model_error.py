"""The model-error table and the main job's line, from stored ladders (docs/model.md sec. 10)."""
import json
import os

import pytest

from run.report import voxel_model_error as V
from run.report.voxel_write import section_voxel

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

R = 12.5e-6
C0 = {"Ex": 160e9, "Ey": 150e9, "Ez": 140e9, "G_yz": 60e9, "G_xz": 61e9, "G_xy": 62e9}
FRAME = {k: 2.5 * v for k, v in C0.items()}


def ladder():
    """A run/report/voxel_ladder.py record whose constants follow C0 (1 + 2 (H/R)^1.5) exactly."""
    levels = []
    for n in (4, 6, 8, 12):
        h = R / n
        levels.append({"per_radius": n, "voxel_size": h, "voxels": [n] * 3, "dofs": 3 * n ** 3,
                       "solid_fraction": 0.9, "necks_resolved_share": 1.0, "seconds": n,
                       "peak_rss_bytes": n * 2**20, "iterations": [9] * 6, "warnings": [],
                       "properties": {k: v * (1 + 2 * (h / R) ** 1.5) for k, v in C0.items()}})
    return {"label": "synthetic", "bc": "kubc", "mean_radius": R, "ranks": 2, "machine": "m",
            "date": "2026-12-03", "levels": levels,
            "frame": {"properties": FRAME, "seconds": 1.5, "peak_rss_bytes": 2**27,
                      "n_particles": 600, "n_removed": 0}}


def test_the_table_extrapolates_and_divides(tmp_path):
    entry = V.bed_entry(ladder())
    for k, v in (C0 | {"E_mean": 150e9}).items():
        assert entry["continuum"][k]["value"] == pytest.approx(v, rel=1e-10)
        assert entry["ratio"][k]["value"] == pytest.approx(2.5, rel=1e-10)
        assert entry["ratio"][k]["error"] == pytest.approx(
            2.5 * entry["continuum"][k]["error"] / v, rel=1e-10)
    store = tmp_path / "store.json"
    store.write_text(json.dumps({"beds": {V.HEADLINE_BED: entry}}))
    line = V.headline(str(store))
    err = entry["ratio"][V.HEADLINE_KEY]["error"]
    assert err > 0.05                  # the GCI of an observed order: 1.25 x the last step
    assert f"read 2.5 +- {err:.1f} x the continuum" in line and "frame 375 GPa" in line
    assert f"150 +- {entry['continuum']['E_mean']['error'] / 1e9:.0f} GPa" in line
    assert "2026-12-03" in line
    # the report's section reads the same store from a root's docs/
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "voxel_model_error.json").write_text(store.read_text())
    md = "\n".join(section_voxel(str(tmp_path)))
    assert "| synthetic (kubc) | frame | 400.0 | 375.0 | 350.0 | 375.0 | 150.0 | 1.5 |" in md
    assert f"2.50 +- {err:.2f}" in md


def test_without_a_store_the_line_says_so_and_the_report_skips(tmp_path):
    assert V.headline(str(tmp_path / "none.json")).startswith("model error: no stored")
    assert section_voxel(str(tmp_path)) == []


def test_update_adds_a_ladder_and_keeps_the_stored_beds(tmp_path):
    old = {"source": "s", "beds": {"kept": V.bed_entry(ladder())},
           "roberts_garboczi": {"cells": []}}
    store, new, out = tmp_path / "store.json", tmp_path / "new.json", tmp_path / "out.json"
    store.write_text(json.dumps(old))
    lad = ladder()
    lad["label"] = "added"
    lad["frame"]["properties"] = {k: 2.0 * v for k, v in C0.items()}
    new.write_text(json.dumps(lad))
    assert V.main(["--update", str(store), "--ladder", f"added={new}", "-o", str(out)]) == 0
    got = json.loads(out.read_text())
    assert sorted(got["beds"]) == ["added", "kept"] and "roberts_garboczi" in got
    assert got["beds"]["kept"] == json.loads(json.dumps(old["beds"]["kept"]))
    assert got["beds"]["added"]["ratio"]["Ex"]["value"] == pytest.approx(2.0, rel=1e-10)
