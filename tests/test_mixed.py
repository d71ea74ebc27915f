"""Mixed boundary conditions (paper figure 2) and the solver diagnostics."""
import json

import numpy as np
import pytest
from helpers import cubic_lattice, homogenize_arrays, run_cli

from amfe.io.bedfile import write_bed
from amfe.model.bed import generate_bed
from amfe.model.frame import build_frame


@pytest.mark.parametrize("n", [3, 4])
def test_mixed_simple_cubic_lattice_analytic(n):
    # frictionless grips on x faces: n^2 chains of n-1 bonds in series carry the load,
    # no Poisson coupling: Ex = (k_n / s) n^2 / (n-1)^2 as under KUBC with the hull volume,
    # times V_hull / V with V the spheres' box (docs/model.md, section 5), nu = 0
    s = 1.8e-6
    x, r = cubic_lattice(n, spacing=s)
    frame = build_frame(x, r)
    k_n = frame.k_n[0] * frame.force_scale / frame.length_scale
    res = homogenize_arrays(x, r, bc="mixed", rtol=1e-12)
    assert res["bc"] == "mixed"
    for key in ("Ex", "Ey", "Ez"):
        assert res["properties"][key] == pytest.approx(
            k_n / s * n**2 / (n - 1) ** 2 * ((n - 1) * s / ((n - 1) * s + 2 * r[0])) ** 3,
            rel=1e-8)
    for key in ("nu_yz", "nu_xz", "nu_xy"):
        assert abs(res["properties"][key]) < 1e-8


@pytest.mark.parametrize("seed", [1, 2])
def test_kubc_is_stiffer_than_mixed_in_every_normal_direction(seed):
    bed = generate_bed(size=(150e-6, 150e-6, 100e-6), seed=seed)
    kubc = homogenize_arrays(bed.centers, bed.radii, rtol=1e-10)
    mixed = homogenize_arrays(bed.centers, bed.radii, bc="mixed", rtol=1e-10)
    for key in ("Ex", "Ey", "Ez"):
        gap = kubc["properties"][key] / mixed["properties"][key] - 1
        print(f"seed {seed} {key}: KUBC {kubc['properties'][key]:.4g} Pa, mixed "
              f"{mixed['properties'][key]:.4g} Pa, gap {gap:.2%}")
        assert gap > 0
    # strains are measured: the applied uniaxial case shows lateral contraction
    assert 0 < mixed["properties"]["nu_xy"] < 0.5
    # force-only reactions keep the stress symmetric under mixed conditions too
    assert mixed["solver"]["stress_asymmetry"] < 1e-7


def test_mixed_and_diagnose_under_mpirun(tmp_path):
    bed = tmp_path / "bed.h5"
    write_bed(bed, generate_bed(size=(120e-6, 100e-6, 60e-6), seed=5))
    out = {}
    for ranks in (1, 2):
        path = tmp_path / f"m{ranks}.json"
        proc = run_cli(["homogenize", str(bed), "--bc", "mixed", "--diagnose", "-o", str(path),
                        "--rtol", "1e-12"], ranks=ranks)
        assert proc.returncode == 0, proc.stderr
        out[ranks] = json.loads(path.read_text())
    C1, C2 = np.array(out[1]["C"]), np.array(out[2]["C"])
    assert np.abs(C2 - C1).max() <= 1e-9 * np.abs(C1).max()
    diag = out[2]["diagnostics"]
    assert [d["case"] for d in diag] == ["xx", "yy", "zz", "yz", "xz", "xy"]
    assert [d["iterations"] for d in diag] == out[2]["solver"]["iterations"]
    for d in diag:
        assert d["residual"] < 1e-10
        # CG's Lanczos estimates of the GAMG-preconditioned operator: positive, ordered
        assert 0 < d["eig_min"] <= d["eig_max"] and d["condition"] >= 1
        assert d["grid_complexity"] >= 1 and d["operator_complexity"] >= 1
        assert d["levels"][0] == 6 * out[2]["n_particles"] - 6 * out[2]["n_removed"]
    assert "diagnostics" in proc.stdout and "cond" in proc.stdout


def test_unknown_bc_is_refused():
    x, r = cubic_lattice(3)
    from amfe.errors import AmfeError
    with pytest.raises(AmfeError, match="unknown boundary condition.*kubc, mixed, subc, periodic"):
        homogenize_arrays(x, r, bc="affine")
