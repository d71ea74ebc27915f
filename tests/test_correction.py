"""The reaction stress to second order (amfe.solvers.correction, docs/model.md section 5).

References: a direct solve (Cholesky, exact to round-off) of the same frame, the
definition of the corrections, the one-at-a-time path, and other rank counts.
"""
import json
import subprocess
import sys

import numpy as np
import pytest
from helpers import MPI_ENV, ROOT, homogenize_arrays

from amfe.errors import AmfeError
from amfe.model.averages import strain_from_voigt, unit_strains
from amfe.model.bed import generate_bed
from amfe.model.frame import build_frame
from amfe.model.kubc import kubc_groups
from amfe.model.subc import subc_groups
from amfe.model.torus import periodic_box
from amfe.solvers.correction import (
    CORRECTED_RTOL,
    moment_corrections,
    second_order_kubc,
    second_order_loads,
)


def box_bed():
    """A fully scanned box: every hull vertex is a boundary particle."""
    return generate_bed(size=(0.4e-3, 0.4e-3, 0.2e-3), seed=1)


def round_bed():
    """The box cut to a cylinder: hull vertices on the round side are free under KUBC."""
    bed = box_bed()
    c = bed.centers
    mid = 0.5 * (c.min(axis=0) + c.max(axis=0))
    keep = np.hypot(c[:, 0] - mid[0], c[:, 1] - mid[1]) < 0.2e-3 - 2e-5
    return c[keep], bed.radii[keep]


def error(res, ref):
    """Largest relative difference of the nine constants."""
    return max(abs(res["properties"][k] / v - 1) for k, v in ref["properties"].items())


@pytest.fixture(scope="module")
def box():
    bed = box_bed()
    return bed.centers, bed.radii, homogenize_arrays(bed.centers, bed.radii, solver="cholesky")


@pytest.fixture(scope="module")
def rnd():
    x, r = round_bed()
    return x, r, homogenize_arrays(x, r, solver="cholesky")


def test_corrections_meet_their_definition():
    rng = np.random.default_rng(0)
    D = rng.normal(size=(6, 6))
    oblique = np.stack([strain_from_voigt(v) for v in rng.normal(size=(6, 6))])
    for strains in (unit_strains(), oblique):
        dM = moment_corrections(strains, D)
        assert np.allclose(dM, dM.transpose(0, 2, 1), atol=0)  # symmetric
        # eps_i : dM_j = -D_ij
        assert np.allclose(np.einsum("ikl,jkl->ij", strains, dM), -D, rtol=1e-12, atol=1e-12)
    assert moment_corrections(unit_strains()[:5], D[:5, :5]) is None


def test_second_order_needs_every_hull_vertex_prescribed():
    bed = box_bed()
    frame = build_frame(bed.centers, bed.radii)
    assert second_order_kubc(frame, kubc_groups(frame))
    round_frame = build_frame(*round_bed())
    assert not second_order_kubc(round_frame, kubc_groups(round_frame))
    # SUBC's loads: its own rule, always second order
    assert not second_order_kubc(frame, subc_groups(frame))
    assert second_order_loads(frame, subc_groups(frame))


def errors_over_rtol(x, r, ref, option):
    """{(rtol, "yes" or "no"): error} at rtol 1e-3, 1e-4, 1e-5 with the amfe ``option`` on and
    off; one multigrid for both (the per-bed choice smooths first-order answers)."""
    return {(rtol, value): error(homogenize_arrays(
        x, r, solver="gamg", rtol=rtol,
        ksp_options={option: value, "pc_gamg_agg_nsmooths": "0"}), ref)
        for rtol in (1e-3, 1e-4, 1e-5) for value in ("yes", "no")}


def test_corrected_constants_are_second_order_in_the_residual(box):
    x, r, ref = box
    err = errors_over_rtol(x, r, ref, "amfe_correction")
    for rtol in (1e-3, 1e-4, 1e-5):  # the correction removes the first-order error
        assert err[rtol, "yes"] < 0.03 * err[rtol, "no"], err
    # a decade of rtol gains about two decades of accuracy (one without the correction)
    assert err[1e-4, "yes"] < 0.05 * err[1e-3, "yes"], err
    assert err[1e-5, "yes"] < 1e-6 < err[1e-5, "no"], err


def test_default_rtol_follows_the_order_of_the_answer(box):
    x, r, ref = box
    res = homogenize_arrays(x, r, solver="gamg")
    s = res["solver"]
    assert s["rtol"] == CORRECTED_RTOL and 0 < s["correction"] < 1e-3
    assert error(res, ref) < 1e-6
    # the same multigrid (uncorrected, the per-bed choice would smooth): the rtol's effect
    plain = homogenize_arrays(x, r, solver="gamg", ksp_options={"amfe_correction": "no",
                                                                "pc_gamg_agg_nsmooths": "0"})
    assert plain["solver"]["rtol"] == 1e-8 and "correction" not in plain["solver"]
    assert max(s["iterations"]) < 0.75 * max(plain["solver"]["iterations"])
    assert error(res, ref) < 2 * error(plain, ref)  # as accurate as before, or better
    xc, rc = round_bed()
    # free hull vertices without the strain's adjoints (tests/test_strain_adjoint.py): first order
    rnd = homogenize_arrays(xc, rc, solver="gamg", ksp_options={"amfe_strain_adjoint": "no"})
    assert rnd["solver"]["rtol"] == 1e-8 and rnd["solver"]["correction"] > 0
    assert error(rnd, homogenize_arrays(xc, rc, solver="cholesky")) < 1e-6


def test_the_option_with_petscs_dash_sets_the_default_rtol_too(box):
    # the operator strips the dash; the default rtol must follow the same value, or the
    # uncorrected stress would run at the corrected rtol 1e-5
    x, r, _ = box
    res = homogenize_arrays(x, r, solver="gamg", ksp_options={"-amfe_correction": "no"})
    assert res["solver"]["rtol"] == 1e-8 and "correction" not in res["solver"]


# the stress's correction on the box; the strain's adjoints on a bed with free hull vertices
# (tests/test_strain_adjoint.py): (fixture, option, what the result reports)
OPTIONS = [("box", "amfe_correction", "correction"),
           ("rnd", "amfe_strain_adjoint", "strain_correction")]


@pytest.mark.parametrize("bed, option, stat", OPTIONS)
def test_both_paths_are_corrected_alike(request, bed, option, stat):
    x, r, ref = request.getfixturevalue(bed)
    for block in ("yes", "no"):
        res = homogenize_arrays(x, r, solver="gamg", rtol=1e-5,
                                ksp_options={"amfe_block": block, option: "yes"})
        assert error(res, ref) < 1e-6, block
        assert res["solver"][stat] > 0


@pytest.mark.parametrize("bed, option, stat", OPTIONS)
def test_a_bad_correction_option_is_refused(request, bed, option, stat):
    x, r, _ = request.getfixturevalue(bed)
    with pytest.raises(AmfeError, match=f"-{option} 'maybe': give yes"):
        homogenize_arrays(x, r, solver="gamg", ksp_options={option: "maybe"})


@pytest.mark.parametrize("bc", ["subc", "periodic"])
def test_the_loads_work_is_second_order_too(bc):
    # SUBC (S = F . U / V) and the periodic condition (C = (W0 - F . U) / V): + D, - D
    bed = generate_bed((150e-6, 150e-6, 100e-6), seed=4, periodic=True)
    kw = dict(bc=bc, box=periodic_box(bed) if bc == "periodic" else None, solver="gamg")
    ref = homogenize_arrays(bed.centers, bed.radii, rtol=1e-12, **kw)
    err = {c: error(homogenize_arrays(bed.centers, bed.radii, rtol=1e-4,
                                      ksp_options={"amfe_correction": c,
                                                   "pc_gamg_agg_nsmooths": "0"}, **kw), ref)
           for c in ("yes", "no")}
    assert err["yes"] < 0.03 * err["no"], err
    res = homogenize_arrays(bed.centers, bed.radii, **kw)
    assert res["solver"]["rtol"] == CORRECTED_RTOL and res["solver"]["correction"] > 0
    assert error(res, ref) < 1e-6


SCRIPT = r"""
import json
from amfe.solvers.petsc import init_petsc
PETSc = init_petsc()
from amfe.model.bed import Bed, generate_bed
from amfe.model.options import SolveOptions
from amfe.solvers.driver import homogenize_bed
bed = generate_bed(size=(0.4e-3, 0.4e-3, 0.2e-3), seed=1)   # as arrays: V as the reference's
res = homogenize_bed(Bed(bed.centers, bed.radii), SolveOptions(solver="gamg")).to_dict()
if PETSc.COMM_WORLD.getRank() == 0:
    print("RESULT " + json.dumps({"properties": res["properties"], "solver": {
        "rtol": res["solver"]["rtol"], "correction": res["solver"]["correction"]}}), flush=True)
"""


@pytest.mark.parametrize("ranks", [2, 3])
def test_corrected_default_on_several_ranks(tmp_path, box, ranks):
    _, _, ref = box
    script = tmp_path / "corrected.py"
    script.write_text(SCRIPT)
    proc = subprocess.run(["mpirun", "-n", str(ranks), sys.executable, str(script)],
                          capture_output=True, text=True, cwd=ROOT, env=MPI_ENV, timeout=60)
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads([s for s in proc.stdout.splitlines() if s.startswith("RESULT ")][0][7:])
    assert res["solver"]["rtol"] == CORRECTED_RTOL
    assert error(res, ref) < 1e-6


def test_tori_take_unsmoothed_aggregation_at_the_corrected_default(monkeypatch):
    from amfe.model import periodic
    bed = generate_bed((150e-6, 150e-6, 100e-6), seed=4, periodic=True)
    its = {}
    for smoothed_from, rtol in ((0, None), (10**9, None), (0, 1e-8), (10**9, 1e-8)):
        monkeypatch.setattr(periodic, "SMOOTHED_FROM", smoothed_from)
        res = homogenize_arrays(bed.centers, bed.radii, bc="periodic", box=periodic_box(bed),
                             solver="gamg", rtol=rtol)
        its[smoothed_from, rtol] = res["solver"]["iterations"]
    assert its[0, None] == its[10**9, None]  # rtol 1e-5: unsmoothed, whatever the size
    assert max(its[0, 1e-8]) < max(its[10**9, 1e-8])  # tighter: large tori smoothed
