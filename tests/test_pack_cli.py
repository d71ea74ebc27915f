"""`amfe pack`: in-process and as a subprocess; bad input leaves no file."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from amfe.cli import main
from amfe.dataset.density import solid_fraction
from amfe.io.bedfile import read_bed
from amfe.model.bed import generate_bed
from amfe.model.scanpath import ScanPath

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--size", "0.15", "0.15", "0.1"]


def test_default_is_the_papers_figure_2_bed(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["pack"]) == 0
    out = capsys.readouterr().out
    bed = read_bed(tmp_path / "bed.h5")
    ref = generate_bed((0.25e-3, 0.25e-3, 0.1e-3), seed=0)
    assert np.array_equal(bed.centers, ref.centers)
    assert np.array_equal(bed.radii, ref.radii)
    assert bed.attrs == ref.attrs
    assert f"particles         {ref.n} " in out
    assert f"mean radius       {ref.radii.mean() * 1e6:.4f} um" in out
    # the union's fraction, below the sum of the sphere volumes (which counts each neck twice)
    phi = solid_fraction(ref.centers, ref.radii, np.zeros(3), ref.attrs["size"])[0]
    assert f"solid fraction    {phi:.4f} " in out
    assert phi < np.sum(4 / 3 * np.pi * ref.radii**3) / np.prod(ref.attrs["size"]) - 0.01
    assert f"shrunk particles  {ref.attrs['n_shrunk']} " in out
    assert "bed.h5" in out


def test_options_reach_the_generator(tmp_path, capsys):
    path = tmp_path / "b.h5"
    argv = ["pack", "-o", str(path), *SMALL, "--seed", "3", "--enlargement", "1.06", "1.12",
            "--jitter", "0.02", "--a-star-max", "0.95", "--track-width", "0.05",
            "--hatch-spacing", "0.07", "--angle", "30", "--layer-rotation", "90",
            "--skip-fraction", "0.2", "--skip-length", "0.04", "--offset", "0.01"]
    assert main(argv) == 0
    bed = read_bed(path)
    scan = ScanPath(track_width=0.05e-3, hatch_spacing=0.07e-3, angle=30, layer_rotation=90,
                    skip_fraction=0.2, skip_length=0.04e-3, offset=0.01e-3)
    ref = generate_bed((0.15e-3, 0.15e-3, 0.1e-3), seed=3, enlargement=(1.06, 1.12),
                       jitter=0.02, a_star_max=0.95, scan=scan)
    assert np.array_equal(bed.centers, ref.centers)
    assert np.array_equal(bed.radii, ref.radii)
    assert bed.attrs["scan"] == "raster" and bed.attrs["a_star_max"] == 0.95
    assert bed.n < bed.attrs["n_lattice"]


def test_subprocess(tmp_path):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    r = subprocess.run([sys.executable, "-m", "amfe.cli", "pack", *SMALL, "--seed", "2"],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "written           bed.h5" in r.stdout
    bed = read_bed(tmp_path / "bed.h5")
    assert np.array_equal(bed.radii, generate_bed((0.15e-3, 0.15e-3, 0.1e-3), seed=2).radii)


@pytest.mark.parametrize("args, match", [
    (["--size", "0.15", "-0.15", "0.1"], "--size must be three positive"),
    (["--size", "0.15", "0", "0.1"], "--size must be three positive"),
    (["--enlargement", "1.14", "1.05"], "LO <= HI"),
    (["--enlargement", "0.9", "1.05"], "enlargement must satisfy"),
    (["--a-star-max", "0.9934"], "critical"),
    (["--a-star-max", "1.2"], "critical"),
    (["--seed", "-3"], "seed"),
    (["--jitter", "-0.1"], "jitter"),
    (["--track-width", "0.05"], "needs --hatch-spacing"),
    (["--angle", "30"], "needs --track-width and --hatch-spacing"),
    (["--track-width", "-0.05", "--hatch-spacing", "0.1"], "track width must be positive"),
    (["--track-width", "0.05", "--hatch-spacing", "0.1", "--skip-fraction", "1"], "skip fraction"),
    (["--size", "0.01", "0.15", "0.1"], "holds no particle"),
])
def test_bad_input(tmp_path, capsys, args, match):
    path = tmp_path / "bed.h5"
    rc = main(["pack", "-o", str(path), *SMALL, *args])
    err = capsys.readouterr().err
    assert rc != 0
    assert err.startswith("amfe pack: error:") and match in err
    assert list(tmp_path.iterdir()) == []


def test_bad_input_subprocess(tmp_path):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    r = subprocess.run([sys.executable, "-m", "amfe.cli", "pack", "--enlargement", "1.2", "1.1"],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert "LO <= HI" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_unparsable_number_is_an_argparse_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["pack", "-o", str(tmp_path / "b.h5"), "--seed", "x"])
    assert exc.value.code != 0
    assert "invalid int value" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_output_directory_missing(tmp_path, capsys):
    rc = main(["pack", "-o", str(tmp_path / "no" / "b.h5"), *SMALL])
    assert rc == 2 and "does not exist" in capsys.readouterr().err
