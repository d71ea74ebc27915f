"""The boundary-condition table (amfe.model.conditions): a condition defined and registered in
this file alone runs end to end, through amfe.homogenize and the command line."""
import dataclasses
import json

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from cli_fixtures import run_main

import amfe
from amfe.errors import AmfeError
from amfe.io.result_meta import validate
from amfe.model.averages import box_center, unit_strains
from amfe.model.carrying import kubc_carrying
from amfe.model.conditions import CONDITIONS, Condition, get_condition, register, unregister
from amfe.model.frame import build_frame
from amfe.model.kubc import kubc_displacements
from amfe.model.loadcase import Group
from amfe.model.options import SolveOptions
from amfe.solvers.scipy_direct import global_stiffness
from amfe.vocab import CASE_NAMES


def thick_groups(frame):
    """KUBC with a boundary layer two largest radii deep (KUBC's is one): more prescribed
    particles, a stiffer frame."""
    x, r = frame.centers, frame.radii
    lo, hi = x.min(axis=0), x.max(axis=0)
    boundary = np.any((x - lo <= 2 * r.max()) | (hi - x <= 2 * r.max()), axis=1)
    fixed = np.zeros((len(x), 6), bool)
    fixed[boundary, :3] = True
    values = []
    for eps in unit_strains():
        v = np.zeros((len(x), 6))
        v[:, :3] = kubc_displacements(x, box_center(x), eps)
        values.append(v)
    return [Group(fixed=fixed, values=values, names=list(CASE_NAMES), guesses=values)]


def first_order(frame, groups):
    """The toy's own second-order test: it has none (a test-file function, not a name)."""
    return False


THICK = Condition("kubc_thick", thick_groups, kubc_carrying, "amfe.solvers.driver:bagi_average",
                  first_order, help="KUBC two radii deep (a test's)")
COPY = Condition("kubc_copy", get_condition("kubc").groups, kubc_carrying,
                 "amfe.solvers.driver:bagi_average", first_order, help="KUBC again (a test's)")


@pytest.fixture
def toys():
    for c in (THICK, COPY):
        register(c)
    yield
    for c in (THICK, COPY):
        unregister(c.name)


@pytest.fixture(scope="module")
def bed():
    return amfe.generate_bed(size=(0.15e-3, 0.15e-3, 0.1e-3), seed=3)


def test_a_copy_of_kubc_registered_here_gives_kubcs_constants(toys, bed):
    kubc = amfe.homogenize(bed, solver="cholesky")
    copy = amfe.homogenize(bed, bc="kubc_copy", solver="cholesky")
    assert copy.bc == "kubc_copy"
    assert np.allclose(copy.C, kubc.C, rtol=1e-9, atol=1e-9 * np.abs(kubc.C).max())


def test_a_thicker_grip_registered_here_is_stiffer_in_every_direction(toys, bed):
    kubc = amfe.homogenize(bed, solver="cholesky").C
    thick = amfe.homogenize(bed, bc="kubc_thick", solver="cholesky").C
    assert np.allclose(thick, thick.T, rtol=0, atol=1e-6 * np.abs(thick).max())
    rng = np.random.default_rng(0)
    for e in rng.standard_normal((200, 6)):   # e.C.e: more prescribed DOFs, more energy
        assert e @ thick @ e >= e @ kubc @ e * (1 - 1e-9)
    assert np.trace(thick) > np.trace(kubc) * (1 + 1e-3)


def test_the_command_line_and_the_schema_take_it(toys, bed, tmp_path):
    path = tmp_path / "bed.h5"
    amfe.write_bed(path, bed)
    code, out, err = run_main(["homogenize", path, "--bc", "kubc_thick", "--quiet",
                               "-o", tmp_path / "r.json"])
    assert code == 0, err
    with open(tmp_path / "r.json") as f:
        result = json.load(f)
    assert result["bc"] == "kubc_thick"
    validate(result)
    code, _, err = run_main(["homogenize", path, "--bc", "kubc_thin", "--quiet"])
    assert code == 2 and "kubc_thin" in err and "kubc_thick" in err   # argparse's choices


def test_an_unregistered_name_is_refused_naming_the_table(bed):
    assert "kubc_thick" not in CONDITIONS
    with pytest.raises(AmfeError, match="unknown boundary condition 'kubc_thick'.*kubc, mixed"):
        SolveOptions(bc="kubc_thick")


def test_the_table_lists_amfes_own_and_what_each_needs():
    assert list(CONDITIONS)[:4] == ["kubc", "mixed", "subc", "periodic"]
    assert [n for n, c in CONDITIONS.items() if c.periodic] == ["periodic"]
    assert get_condition("subc").loads == "stress" and get_condition("kubc").hull_strain


def test_the_schema_reads_the_names_from_the_table(toys):
    from helpers import ROOT
    with open(f"{ROOT}/tests/data/golden_result_mixed_gamg.json") as f:
        result = json.load(f)
    validate({**result, "bc": "kubc_thick"})        # registered: a name the schema takes
    unregister("kubc_thick")
    with pytest.raises(AmfeError, match="bc"):
        validate({**result, "bc": "kubc_thick"})


def held_rotation_groups(frame):
    """KUBC's six cases with the boundary particles' rotations held at zero too (the affine
    field's rotation under a symmetric strain)."""
    (g,) = get_condition("kubc").groups(frame)
    fixed = g.fixed.copy()
    fixed[g.fixed[:, :3].any(axis=1), 3:] = True
    return [dataclasses.replace(g, fixed=fixed)]


def energy_stiffness(bed, groups_of, volume):
    """C (6, 6) [Pa] = U^T K U / V by SuperLU, every prescribed DOF at its value: Hill's
    identity, independent of the driver's averages. volume: V [m^3] (the result's)."""
    frame = build_frame(bed.centers, bed.radii)
    (g,) = groups_of(frame)
    K = global_stiffness(frame)
    pres = np.flatnonzero(g.fixed.ravel())
    free = np.setdiff1d(np.arange(K.shape[0]), pres)
    U = np.array([np.asarray(v, float).ravel() for v in g.values]).T    # (6n, 6)
    U[free] = spla.splu(K[free][:, free].tocsc()).solve(-(K[free][:, pres] @ U[pres]))
    return (U.T @ (K @ U)) / (volume / frame.length_scale**3) * frame.stress_scale


HELD = Condition("kubc_held_rotations", held_rotation_groups, kubc_carrying,
                 "amfe.solvers.driver:bagi_average", first_order,
                 help="KUBC with the boundary rotations held (a test's)")


def test_held_rotations_registered_here_match_an_independent_energy(bed):
    """C of a condition defined here equals U^T K U / V of a SuperLU solve (to rounding), as
    KUBC's does, and lies above KUBC's (more constraints) without being KUBC's."""
    register(HELD)
    try:
        held = amfe.homogenize(bed, bc=HELD.name, solver="cholesky")
    finally:
        unregister(HELD.name)
    kubc = amfe.homogenize(bed, solver="cholesky")
    C, Ck = np.asarray(held.C), np.asarray(kubc.C)
    scale = np.abs(Ck).max()
    assert np.abs(C - energy_stiffness(bed, held_rotation_groups, held.volume)).max() < 1e-9 * scale
    assert np.abs(Ck - energy_stiffness(bed, get_condition("kubc").groups, kubc.volume)).max() \
        < 1e-9 * scale
    gap = np.linalg.eigvalsh((C - Ck + (C - Ck).T) / 2)
    assert gap.min() > -1e-9 * scale and gap.max() > 1e-4 * scale
