"""SUBC beside KUBC (docs/model.md, section 9): weights, loads, exact lattice values,
the energy ordering e:C_subc:e <= e:C_kubc:e, and `amfe homogenize --bc subc|all`."""
import json

import numpy as np
import pytest
from helpers import cubic_lattice, homogenize_arrays, run_cli
from test_hard_cases import NEAR_MECHANISMS, near_critical_interior_bed

from amfe.errors import AmfeError
from amfe.io.bedfile import write_bed
from amfe.model.averages import box_center, hull_of, symmetric
from amfe.model.bed import Bed, generate_bed
from amfe.model.carrying import bed_box
from amfe.model.frame import build_frame
from amfe.model.kubc import boundary_particles
from amfe.model.periodic import love_weber_stiffness
from amfe.model.scales import sample_bed_params
from amfe.model.scanpath import ScanPath
from amfe.model.subc import (
    check_boundary_spans_volume,
    energy_gap,
    kubc_admissible_strain,
    subc_average,
    subc_groups,
    subc_strain,
    subc_weights,
)
from amfe.solvers.scipy_direct import group_solve_scipy, kubc_stiffness_scipy

SPACING, RADIUS = 1.8e-6, 1e-6          # simple cubic lattice: sqrt(2) r < s < 2 r
STRAINS = np.vstack([np.eye(6), np.random.default_rng(7).normal(size=(30, 6))])


def subc_scipy(frame):
    """(C, u, groups) of SUBC by SuperLU (non-dimensional)."""
    groups = subc_groups(frame)
    u = group_solve_scipy(frame, groups[0])
    return subc_average(frame, groups, u)[0], u, groups


def hcp_frame(seed, scan=None, size=(150e-6, 150e-6, 100e-6)):
    bed = generate_bed(size, seed=seed, scan=scan)
    return build_frame(bed.centers, bed.radii)


# --------------------------------------------------------------------------- #
# weights, loads, averages
# --------------------------------------------------------------------------- #
def test_weights_meet_the_twelve_conditions_and_kubc_field_is_admissible():
    fr = hcp_frame(1)
    V = hull_of(fr.centers).volume
    idx, a, correction = subc_weights(fr.centers, fr.radii, V)
    xr = fr.centers[idx] - box_center(fr.centers)
    assert np.abs(a.sum(axis=0)).max() < 1e-12 * V ** (2 / 3)
    assert np.abs(np.einsum("bi,bj->ij", a, xr) - V * np.eye(3)).max() < 1e-12 * V
    assert 0 < correction < 0.2                       # measured 0.05
    assert np.array_equal(idx, np.flatnonzero(boundary_particles(fr.centers, fr.radii)))
    # KUBC's affine boundary field has the applied strain as its SUBC strain
    assert np.abs(kubc_admissible_strain(fr) - np.eye(6)).max() < 1e-12


def test_loads_are_self_equilibrated_and_the_average_stress_is_the_applied_one():
    fr = hcp_frame(2)
    C, u, groups = subc_scipy(fr)
    F = np.asarray(groups[0].forces)                 # (6, n, 6)
    x = fr.centers - box_center(fr.centers)
    assert np.abs(F.sum(axis=1)).max() < 1e-12 * np.abs(F).max()          # no net force
    mom = np.einsum("cni,nj->cij", F[:, :, :3], x)
    assert np.abs(mom - np.transpose(mom, (0, 2, 1))).max() < 1e-12 * np.abs(mom).max()
    assert not F[:, :, 3:].any()                                          # no couples
    V = fr.volume                                    # the bed's box, which the loads measure
    sig, _ = love_weber_stiffness(fr, u, volume=V)   # from the solved bond forces
    assert np.abs(sig - np.eye(6)).max() < 1e-9
    # the work form S = F.U/V used by the driver equals the weights' strain
    idx, a, _ = subc_weights(fr.centers, fr.radii, V, fr.parts)
    S_strain = subc_strain(u, idx, a, V).T
    assert np.abs(np.linalg.inv(C) - S_strain).max() < 1e-9 * np.abs(S_strain).max()


def test_petsc_subc_matches_the_direct_solve():
    bed = generate_bed((150e-6, 150e-6, 100e-6), seed=5)
    res = homogenize_arrays(bed.centers, bed.radii, bc="subc", rtol=1e-12)
    fr = build_frame(bed.centers, bed.radii)
    C_ref = subc_scipy(fr)[0] * fr.stress_scale
    C = np.array(res["C"])
    assert np.abs(C - C_ref).max() < 1e-9 * np.abs(C_ref).max()
    assert res["bc"] == "subc" and res["solver"]["S_asymmetry"] < 1e-9
    assert res["volume"] == pytest.approx(fr.volume * fr.length_scale**3, rel=1e-12)
    assert res["volume"] == pytest.approx(np.prod(bed_box(bed.centers, bed.radii)[0]), rel=1e-12)


def test_subc_galerkin_algorithm_is_chosen_per_rank_count_and_changes_nothing():
    """SUBC's smoothed aggregation forms P^T A P by "rap" (serial) or "nonscalable"
    (parallel), unless the user names one; PETSc's default gives the same C."""
    from amfe.solvers.blocksolve import with_block_defaults
    from amfe.solvers.petsc import init_petsc
    init_petsc()
    assert with_block_defaults({}, True, 1) == {"matptap_via": "rap"}
    assert with_block_defaults({}, True, 3) == {"matptap_via": "nonscalable"}
    assert with_block_defaults({"matptap_via": "scalable"}, True, 2) == {
        "matptap_via": "scalable"}
    assert "matptap_via" not in with_block_defaults({}, False, 1)
    bed = generate_bed((150e-6, 150e-6, 100e-6), seed=5)
    C = [np.array(homogenize_arrays(bed.centers, bed.radii, bc="subc", rtol=1e-12,
                                 ksp_options=opts)["C"])
         for opts in (None, {"matptap_via": "scalable"})]
    assert np.abs(C[0] - C[1]).max() < 1e-9 * np.abs(C[1]).max()


# --------------------------------------------------------------------------- #
# analytic lattices
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("n", [3, 4, 5])
def test_cubic_lattice_normal_moduli_are_exact_for_both(n):
    """The chains decouple: uniform force = uniform displacement, so KUBC = SUBC =
    (k_n / s) n^2 / (n - 1)^2 with the hull volume ((n-1) s)^3, times V_hull / V with V the
    bed's box (here the spheres'), and the face shares need no correction."""
    fr = build_frame(*cubic_lattice(n, SPACING, RADIUS))
    s = SPACING / RADIUS
    expect = fr.k_n[0] / s * n**2 / (n - 1) ** 2 * ((n - 1) * s) ** 3 / fr.volume
    Ck = kubc_stiffness_scipy(fr)[0]
    Cs = subc_scipy(fr)[0]
    for k in range(3):
        assert Ck[k, k] == pytest.approx(expect, rel=1e-12)
        assert Cs[k, k] == pytest.approx(expect, rel=1e-10)
    assert subc_weights(fr.centers, fr.radii, fr.volume)[2] < 1e-12
    assert energy_gap(symmetric(Ck), Cs, STRAINS) >= -1e-12
    assert Cs[5, 5] < Ck[5, 5]                         # shear: SUBC strictly softer


# --------------------------------------------------------------------------- #
# the energy ordering on every kind of bed
# --------------------------------------------------------------------------- #
def _lattice_beds():
    return {f"cubic {n}": cubic_lattice(n, SPACING, RADIUS) for n in (3, 6)}


def _hard_beds():
    beds = {"near-critical interior a*=0.99": near_critical_interior_bed(0.99)}
    for name in ("block+chain of 60", "two blocks + track of 9"):
        beds[name] = NEAR_MECHANISMS[name]()
    return beds


def _generated_beds():
    scan = ScanPath(track_width=60e-6, hatch_spacing=80e-6, angle=30.0, skip_fraction=0.2,
                    skip_length=80e-6)
    beds = {"hcp full seed 1": generate_bed((150e-6, 150e-6, 100e-6), seed=1),
            "hcp raster seed 3": generate_bed((150e-6, 150e-6, 100e-6), seed=3, scan=scan)}
    for seed in (1, 2, 3, 7):                         # `tiny` data-set beds (4, 5 are degenerate)
        beds[f"tiny record seed {seed}"] = generate_bed(**sample_bed_params("tiny", seed))
    return {k: (b.centers, b.radii) for k, b in beds.items()}


ORDERING_BEDS = {**_lattice_beds(), **_hard_beds(), **_generated_beds()}


@pytest.mark.parametrize("name", list(ORDERING_BEDS))
def test_subc_is_below_kubc_in_energy(name):
    x, r = ORDERING_BEDS[name]
    fr = build_frame(x, r)
    Cs = subc_scipy(fr)[0]
    Ca = symmetric(kubc_stiffness_scipy(fr, "applied")[0])
    assert energy_gap(Ca, Cs, STRAINS) >= -1e-10     # a theorem with KUBC's applied strain
    prescribed = boundary_particles(fr.centers, fr.radii)[hull_of(fr.centers).vertices].all()
    Cb = symmetric(kubc_stiffness_scipy(fr, "bagi")[0])
    if prescribed:                                   # then amfe's Bagi C is the same
        assert np.abs(Cb - Ca).max() < 1e-9 * np.abs(Ca).max()
        assert energy_gap(Cb, Cs, STRAINS) >= -1e-10


# --------------------------------------------------------------------------- #
# refusals and the command line
# --------------------------------------------------------------------------- #
def test_flat_boundary_sets_are_refused():
    pts = np.zeros((10, 3))
    pts[:, 0] = np.arange(10.0)
    pts[:, 1] = np.arange(10.0) % 3
    with pytest.raises(AmfeError, match="in a plane"):
        check_boundary_spans_volume(pts)
    pts[:, 1] = 0.0
    with pytest.raises(AmfeError, match="on a line"):
        check_boundary_spans_volume(pts)


def test_subc_refuses_a_bed_whose_boundary_is_a_tilted_sheet():
    """A sheet in the plane z = x with one particle bonded off it, inside: the frame spans
    a volume (KUBC's hull exists) but every boundary particle lies in the sheet."""
    g = np.arange(8) * SPACING / np.sqrt(2)
    u, v = np.meshgrid(g, np.arange(8) * SPACING, indexing="ij")
    sheet = np.stack([u.ravel(), v.ravel(), u.ravel()], axis=1)
    mid = sheet[np.argmin(np.sum((sheet - sheet.mean(axis=0)) ** 2, axis=1))]
    bump = mid + SPACING * np.array([-1, 0, 1]) / np.sqrt(2)
    x = np.vstack([sheet, bump])
    with pytest.raises(AmfeError, match="boundary particles lie in a plane"):
        homogenize_arrays(x, np.full(len(x), RADIUS), bc="subc")


@pytest.fixture(scope="module")
def bed_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("bounds") / "bed.h5"
    write_bed(path, generate_bed((120e-6, 120e-6, 80e-6), seed=3))
    return str(path)


def test_cli_bc_all_prints_both_side_by_side_with_the_gap(bed_file, tmp_path):
    out = tmp_path / "all.json"
    proc = run_cli(["homogenize", bed_file, "--bc", "all", "--quiet", "-o", str(out)])
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    assert "== kubc" in text and "== subc" in text and "periodic" not in text.split("== bounds")[0]
    table = text.split("== bounds")[1].splitlines()
    row = next(line for line in table if line.strip().startswith("Ex "))
    k, s, gap = (float(v.rstrip("%")) for v in row.split()[-3:])
    assert s < k and gap == pytest.approx(100 * (k - s) / k, abs=0.02)
    flat = " ".join(text.split())
    assert "energies are ordered" in flat and "but not the Poisson ratios" in flat
    assert "need NOT bracket the periodic value" in flat and "(holds)" in flat
    d = json.loads(out.read_text())
    # with V the bed's box this 90-particle bed reads below E = 210 GPa: no note
    assert ("not a unit error" in flat) == any(
        d["conditions"][c]["properties"][k] > 210e9
        for c in ("kubc", "subc") for k in ("Ex", "Ey", "Ez"))
    assert d["bc"] == "all" and set(d["conditions"]) == {"kubc", "subc"}
    assert d["conditions"]["subc"]["bc"] == "subc" and d["energy_gap"] > 0
    Ck, Cs = (np.array(d["conditions"][c]["C"]) for c in ("kubc", "subc"))
    assert energy_gap(Ck, Cs) == pytest.approx(d["energy_gap"])


def test_cli_periodic_on_a_plain_bed_is_refused(bed_file):
    proc = run_cli(["homogenize", bed_file, "--bc", "periodic", "--quiet"])
    assert proc.returncode == 2
    assert "amfe pack --periodic" in proc.stderr and "Traceback" not in proc.stderr


def test_moduli_note_only_when_above_the_particles_E():
    from amfe.cli.bounds import above_e_note

    props = {k: 100e9 for k in ("Ex", "Ey", "Ez", "G_yz", "G_xz", "G_xy")}
    props.update(nu_yz=0.1, nu_xz=0.1, nu_xy=0.1)
    assert above_e_note(props, 210e9) is None
    props["Ey"] = 300e9
    note = above_e_note(props, 210e9)
    assert note.startswith("note: Ey exceed") and "210 GPa" in note


def test_a_bed_object_with_periodic_attr_is_read_back(tmp_path):
    """Bed files carry `periodic` through a write/read round trip, and refuse a bad one."""
    from amfe.io.bedfile import read_bed

    bed = generate_bed((100e-6, 100e-6, 100e-6), seed=2, periodic=True)
    write_bed(tmp_path / "p.h5", bed)
    back = read_bed(tmp_path / "p.h5")
    assert back.attrs["periodic"] == bed.attrs["periodic"]
    write_bed(tmp_path / "bad.h5", Bed(bed.centers, bed.radii, {"periodic": [1e-6, 1e-4, 1e-4]}))
    with pytest.raises(AmfeError, match="too small"):
        read_bed(tmp_path / "bad.h5")


def test_dataset_labels_can_be_subc(tmp_path):
    import h5py

    out = tmp_path / "subc.h5"
    proc = run_cli(["dataset", "-o", str(out), "--count", "3", "--seed", "5", "--scale", "tiny",
                    "--bc", "subc", "--no-progress", "--max-failed-share", "1"])
    assert proc.returncode == 0, proc.stderr
    with h5py.File(out, "r") as f:
        assert f.attrs["bc"] == "subc"
        labels, seeds, status = f["labels"][()], f["seed"][()], f["status"][()]
    assert (status == 0).sum() >= 2
    for k in np.flatnonzero(status == 0):
        bed = generate_bed(**sample_bed_params("tiny", int(seeds[k])))
        size = bed.attrs["size"]                      # the labels' V: the bed's own box
        res = homogenize_arrays(bed.centers, bed.radii, bed.material(), bc="subc", solver="auto",
                             size=size)
        assert res["properties"]["Ex"] == pytest.approx(labels[k, 0], rel=1e-9)
        kubc = homogenize_arrays(bed.centers, bed.radii, bed.material(), size=size)
        assert labels[k, 0] < kubc["properties"]["Ex"]
