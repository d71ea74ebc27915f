"""Periodic beds and the periodic condition (docs/model.md, section 9): generation, the
torus frame, exact lattice values, the three stiffness forms, invariance, ranks, VTU."""
import hashlib
import json

import numpy as np
import pytest
from helpers import cubic_lattice, homogenize_arrays, run_cli

from amfe.errors import AmfeError
from amfe.io.bedfile import write_bed
from amfe.io.vtu import read_case
from amfe.model import periodic
from amfe.model.bed import generate_bed
from amfe.model.frame import build_frame
from amfe.model.periodic import love_weber_stiffness, periodic_average, periodic_groups
from amfe.model.scales import sample_bed_params
from amfe.model.scanpath import ScanPath
from amfe.model.torus import find_periodic_bonds, hcp_periods, periodic_box
from amfe.solvers.scipy_direct import group_solve_scipy

SPACING, RADIUS = 1.8e-6, 1e-6
SIZE = (150e-6, 150e-6, 100e-6)


def periodic_scipy(frame):
    """(C raw, u) of the periodic condition by SuperLU (non-dimensional)."""
    groups = periodic_groups(frame)
    u = group_solve_scipy(frame, groups[0])
    return periodic_average(frame, groups, u)[0], u


def cubic_torus(n, origin=0.3e-6):
    x, r = cubic_lattice(n, SPACING, RADIUS)
    return build_frame(x + origin, r, box=np.full(3, n * SPACING))


# --------------------------------------------------------------------------- #
# periodic beds
# --------------------------------------------------------------------------- #
def test_periodic_bed_tiles_space():
    bed = generate_bed(SIZE, seed=4, periodic=True)
    L, r0 = periodic_box(bed), bed.attrs["r0"]
    assert np.allclose(L, np.array(bed.attrs["periodic_periods"]) * hcp_periods(r0), rtol=1e-15)
    assert np.allclose(bed.attrs["periodic_snap"], L - np.array(SIZE), rtol=0, atol=1e-18)
    assert np.all(np.abs(bed.attrs["periodic_snap"]) <= 0.5 * hcp_periods(r0) + 1e-18)
    assert bed.attrs["size"] == list(L) and bed.attrs["periodic_requested"] == list(SIZE)
    assert np.all((bed.centers >= 0) & (bed.centers < L))
    bonds, shift = find_periodic_bonds(bed.centers, bed.radii, L)
    assert bonds.a_star.max() <= 0.98 and np.any(shift != 0, axis=1).sum() > 0
    # without enlargement spread or jitter every site has the 12 neighbours of ideal HCP
    ideal = generate_bed(SIZE, enlargement=(1.01, 1.01), jitter=0.0, periodic=True)
    b, _ = find_periodic_bonds(ideal.centers, ideal.radii, periodic_box(ideal))
    assert np.all(np.bincount(np.r_[b.i, b.j], minlength=ideal.n) == 12)


def _digest(bed):
    return hashlib.sha256(bed.centers.tobytes() + bed.radii.tobytes()).hexdigest()[:16]


def test_non_periodic_beds_are_bit_identical_to_before():
    """Digests of beds made by amfe before periodic beds existed (commit 3aaa1fe)."""
    scan = ScanPath(track_width=60e-6, hatch_spacing=80e-6, angle=30.0, skip_fraction=0.2,
                    skip_length=80e-6)
    assert _digest(generate_bed(SIZE, seed=9)) == "1863448a2d7d0cb2"
    assert _digest(generate_bed((200e-6, 150e-6, 100e-6), seed=3, scan=scan)) == "7ec2d089f3c76d8b"
    assert _digest(generate_bed(**sample_bed_params("tiny", 5))) == "6f8aa7c0ae565d14"
    assert "periodic" not in generate_bed(SIZE, seed=9).attrs
    with pytest.raises(AmfeError, match="amfe pack --periodic"):
        periodic_box(generate_bed(SIZE, seed=9))
    with pytest.raises(AmfeError, match="periodic=True"):
        generate_bed(SIZE, offset=(1e-6, 0, 0))


def test_cli_pack_periodic_prints_the_snap(tmp_path):
    out = tmp_path / "p.h5"
    proc = run_cli(["pack", "--periodic", "--size", "0.15", "0.15", "0.1", "--seed", "4",
                    "-o", str(out)])
    assert proc.returncode == 0, proc.stderr
    assert "snapped to whole lattice periods by +0.009817, +0.008178, +0.01185 mm" in proc.stdout
    assert "bonds             2016" in proc.stdout     # crossing bonds counted


# --------------------------------------------------------------------------- #
# analytic: simple cubic lattice on a torus
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("n", [3, 4, 6])
def test_cubic_lattice_is_exact_without_finite_n_correction(n):
    fr = cubic_torus(n)
    assert len(fr.bonds) == 3 * n**3
    kn, kt, s = fr.k_n[0], fr.k_t[0], SPACING / RADIUS
    C, _ = periodic_scipy(fr)
    assert np.allclose(np.diag(C)[:3], kn / s, rtol=1e-13, atol=0)      # C11 = C22 = C33
    assert np.allclose(np.diag(C)[3:], kt / (2 * s), rtol=1e-12, atol=0)  # slide s gamma/2
    assert np.abs(C - np.diag(np.diag(C))).max() < 1e-13 * kn / s       # C12 = 0
    C_lw, asym = love_weber_stiffness(fr, periodic_scipy(fr)[1])
    assert np.abs(C_lw - C).max() < 1e-12 * kn and asym < 1e-12


def test_cubic_lattice_through_petsc():
    fr = cubic_torus(4)
    x, r = cubic_lattice(4, SPACING, RADIUS)
    res = homogenize_arrays(x + 0.3e-6, r, bc="periodic", box=np.full(3, 4 * SPACING), rtol=1e-12)
    C = np.array(res["C"]) / fr.stress_scale
    s = SPACING / RADIUS
    assert np.allclose(np.diag(C), [fr.k_n[0] / s] * 3 + [fr.k_t[0] / (2 * s)] * 3, rtol=1e-9)
    assert res["volume"] == pytest.approx((4 * SPACING) ** 3, rel=1e-14)


def test_bounds_sit_below_the_periodic_value_and_approach_it():
    """Huet's order SUBC <= periodic <= KUBC does not hold: with V the bed's box (n s)^3, the
    one the periodic twin tiles, a finite chain of n particles has n - 1 bonds where the
    torus has n, so C11 = (k_n / s)(n - 1) / n under both finite conditions (they coincide
    on normal strain): 1/n below the periodic value, approached from below
    (docs/model.md, section 9)."""
    per = periodic_scipy(cubic_torus(3))[0]
    gaps = []
    for n in (3, 4, 6):
        x, r = cubic_lattice(n, SPACING, RADIUS)
        fr = build_frame(x, r)
        for bc in ("subc", "kubc"):
            res = homogenize_arrays(x, r, bc=bc, rtol=1e-12, size=[n * SPACING] * 3)
            C = np.array(res["C"]) / fr.stress_scale
            assert C[0, 0] / per[0, 0] - 1 == pytest.approx(-1 / n, rel=1e-8)
        gaps.append(C[0, 0] / per[0, 0] - 1)
    assert np.all(np.diff(gaps) > 0) and gaps[-1] < 0


# --------------------------------------------------------------------------- #
# HCP beds: the three forms agree; invariance; refusals
# --------------------------------------------------------------------------- #
def test_dot_product_energy_and_love_weber_agree_and_petsc_matches(monkeypatch):
    bed = generate_bed(SIZE, seed=4, periodic=True)
    fr = build_frame(bed.centers, bed.radii, box=periodic_box(bed))
    C, u = periodic_scipy(fr)
    C_lw, asym = love_weber_stiffness(fr, u)
    assert np.abs(C_lw - C).max() < 1e-12 * np.abs(C).max() and asym < 1e-12
    res = homogenize_arrays(bed.centers, bed.radii, bc="periodic", box=periodic_box(bed),
                         rtol=1e-12, diagnose=True)
    assert np.abs(np.array(res["C"]) / fr.stress_scale - C).max() < 1e-9 * np.abs(C).max()
    s = res["solver"]
    assert s["love_weber_difference"] < 1e-9 and s["C_asymmetry"] < 1e-9
    assert res["bc"] == "periodic" and res["volume"] == pytest.approx(np.prod(periodic_box(bed)))
    # the block path: unsmoothed aggregation on small tori, smoothed on large ones
    iterations = []
    for smoothed_from in (fr.n_particles + 1, 0):
        monkeypatch.setattr(periodic, "SMOOTHED_FROM", smoothed_from)
        assert periodic_groups(fr)[0].smoothed_aggregation == (smoothed_from == 0)
        res = homogenize_arrays(bed.centers, bed.radii, bc="periodic", box=periodic_box(bed),
                             rtol=1e-12)
        assert np.abs(np.array(res["C"]) / fr.stress_scale - C).max() < 1e-9 * np.abs(C).max()
        iterations.append(max(res["solver"]["iterations"]))
    assert iterations[1] < iterations[0]


def test_results_do_not_change_when_the_bed_is_shifted_by_part_of_a_period():
    Cs = []
    for off in [(0, 0, 0), (3.3e-6, 7.1e-6, 5.5e-6), (-11e-6, 2e-6, 17e-6)]:
        bed = generate_bed(SIZE, seed=4, periodic=True, offset=off)
        Cs.append(periodic_scipy(build_frame(bed.centers, bed.radii, box=periodic_box(bed)))[0])
    for C in Cs[1:]:
        assert np.abs(C - Cs[0]).max() < 1e-10 * np.abs(Cs[0]).max()
    C0, C1 = periodic_scipy(cubic_torus(4, 0.3e-6))[0], periodic_scipy(cubic_torus(4, 1.1e-6))[0]
    assert np.abs(C1 - C0).max() < 1e-12 * np.abs(C0).max()


def test_a_cluster_that_does_not_wrap_in_every_direction_is_refused():
    g = np.arange(4) * SPACING        # two lattice planes repeated in x and y only
    x = np.stack(np.meshgrid(g, g, [0.0, SPACING], indexing="ij"), -1).reshape(-1, 3) + 0.3e-6
    with pytest.raises(AmfeError, match="percolate"):
        build_frame(x, np.full(len(x), RADIUS), box=np.array([4, 4, 6]) * SPACING)


def test_periodic_needs_a_periodic_bed():
    bed = generate_bed(SIZE, seed=9)
    with pytest.raises(AmfeError, match="amfe pack --periodic"):
        homogenize_arrays(bed.centers, bed.radii, bc="periodic")


# --------------------------------------------------------------------------- #
# command line: VTU, and 1, 2, 3 ranks
# --------------------------------------------------------------------------- #
@pytest.fixture(scope="module")
def periodic_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("periodic") / "p.h5"
    write_bed(path, generate_bed((100e-6, 100e-6, 100e-6), seed=6, periodic=True))
    return str(path)


def test_vtu_draws_every_particle_once_and_no_bond_across_the_box(periodic_file, tmp_path):
    proc = run_cli(["homogenize", periodic_file, "--bc", "periodic", "--quiet",
                    "--vtu", str(tmp_path / "vtu"), "-o", str(tmp_path / "r.json")])
    assert proc.returncode == 0, proc.stderr
    res = json.loads((tmp_path / "r.json").read_text())
    mesh = read_case(tmp_path / "vtu" / "case_xx.vtu")
    pts, lines = mesh["points"], mesh["lines"]
    assert len(pts) == res["n_particles"] - res["n_removed"]
    assert 0 < len(lines) < res["n_bonds"]            # the crossing bonds are left out
    assert len(mesh["cell_data"]["axial_force_N"]) == len(lines)
    assert mesh["field_data"]["bonds_not_drawn"] == res["n_bonds"] - len(lines)
    seg = np.linalg.norm(pts[lines[:, 1]] - pts[lines[:, 0]], axis=1)
    assert seg.max() < 2 * 1.14 * 12.5e-6 / 1.095


@pytest.mark.mpi
def test_one_two_and_three_ranks_agree(periodic_file, tmp_path):
    out = {}
    for ranks in (1, 2, 3):
        path = tmp_path / f"r{ranks}.json"
        proc = run_cli(["homogenize", periodic_file, "--bc", "all", "--quiet", "--rtol", "1e-12",
                        "-o", str(path)], ranks=ranks)
        assert proc.returncode == 0, proc.stderr
        out[ranks] = json.loads(path.read_text())["conditions"]
    assert set(out[1]) == {"kubc", "subc", "periodic"}
    for bc in ("subc", "periodic"):
        C1 = np.array(out[1][bc]["C"])
        for ranks in (2, 3):
            assert out[ranks][bc]["ranks"] == ranks
            assert np.abs(np.array(out[ranks][bc]["C"]) - C1).max() <= 1e-9 * np.abs(C1).max()


def test_api_bc_all_on_a_periodic_bed(tmp_path):
    import amfe

    bed = generate_bed((100e-6, 100e-6, 100e-6), seed=6, periodic=True)
    res = amfe.homogenize(bed, bc="all", vtu_dir=str(tmp_path))
    assert list(res) == ["kubc", "subc", "periodic"]
    assert [r.bc for r in res.values()] == list(res)
    assert res["periodic"].volume == pytest.approx(np.prod(bed.attrs["periodic"]))
    assert res["subc"].Ex < res["kubc"].Ex
    assert all((tmp_path / bc / "cases.pvd").exists() for bc in res)
