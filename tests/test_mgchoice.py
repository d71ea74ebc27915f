"""The multigrid choice per bed (amfe.solvers.mgchoice): whole beds keep unsmoothed
aggregation, beds with free hull vertices and many weakly held particles get smoothed
aggregation, the user's -pc_gamg_agg_nsmooths wins, and the constants keep the label
contract (within 1e-5 of a factorisation) at the new default."""
import pytest
from helpers import homogenize_arrays
from test_correction import box_bed, error, round_bed

from amfe.model.frame import build_frame
from amfe.model.kubc import kubc_groups
from amfe.solvers.correction import second_order_kubc
from amfe.solvers.mgchoice import LOW_SHARE_MIN, choose_multigrid, multigrid_features


def features_and_order(centers, radii):
    frame = build_frame(centers, radii)
    return multigrid_features(frame), second_order_kubc(frame, kubc_groups(frame))


def test_a_whole_bed_and_a_cut_bed_get_different_aggregation():
    whole = box_bed()
    f_whole, corrected_whole = features_and_order(whole.centers, whole.radii)
    f_cut, corrected_cut = features_and_order(*round_bed())
    assert corrected_whole and not corrected_cut
    # a test-sized bed is mostly surface: both are above the share, the order decides
    assert f_cut["low_share"] > LOW_SHARE_MIN and f_whole["low_share"] > LOW_SHARE_MIN
    assert choose_multigrid(f_whole, 1, corrected_whole)[0] == {}
    opts, reason = choose_multigrid(f_cut, 1, corrected_cut)
    assert opts["pc_gamg_agg_nsmooths"] == "1" and "smoothed" in reason
    # a bed with free hull vertices but nearly no weakly held particle stays unsmoothed
    assert choose_multigrid({**f_cut, "low_share": LOW_SHARE_MIN / 2}, 1, False)[0] == {}


def test_the_users_nsmooths_wins():
    f, _ = features_and_order(*round_bed())
    assert choose_multigrid(f, 2, False, ["pc_gamg_agg_nsmooths"]) == (
        {}, "-pc_gamg_agg_nsmooths given")
    # only the Galerkin algorithm is the user's: the aggregation is still chosen
    opts, _ = choose_multigrid(f, 2, False, ["matptap_via"])
    assert opts == {"pc_gamg_agg_nsmooths": "1", "mg_levels_ksp_max_it": "2"}


def corner_bed():
    """The box with one vertical edge cut off by an oblique plane (a skipped piece at a
    corner): the hull vertices on the cut are free under KUBC."""
    bed = box_bed()
    c = bed.centers
    s = (c - c.min(axis=0)) / (c.max(axis=0) - c.min(axis=0))   # (N, 3) in [0, 1]
    keep = s[:, 0] + s[:, 1] < 1.5
    return c[keep], bed.radii[keep]


FIRST = {"amfe_strain_adjoint": "no"}


@pytest.fixture(scope="module", params=["round", "corner"])
def cut(request):
    c, r = round_bed() if request.param == "round" else corner_bed()
    return c, r, homogenize_arrays(c, r, solver="cholesky")


def test_the_choice_is_recorded_and_keeps_the_contract(cut):
    c, r, ref = cut
    # first-order constants: the strain's adjoints off (tests/test_strain_adjoint.py)
    res = homogenize_arrays(c, r, solver="gamg", rtol=1e-7, ksp_options=FIRST)
    mg = res["solver"]["multigrid"]
    assert mg["options"]["pc_gamg_agg_nsmooths"] == "1" and "smoothed" in mg["reason"]
    assert error(res, ref) < 1e-5
    mine = homogenize_arrays(c, r, solver="gamg", rtol=1e-7,
                             ksp_options={"-pc_gamg_agg_nsmooths": "0", **FIRST})
    assert mine["solver"]["multigrid"]["options"] == {}
    assert error(mine, ref) < 1e-5
    # on the command line (PETSc's options database, which keeps it: removed after)
    from amfe.solvers.petsclib import PETSc
    try:
        argv = homogenize_arrays(c, r, solver="gamg", rtol=1e-7,
                                 petsc_args=("-pc_gamg_agg_nsmooths", "0"), ksp_options=FIRST)
    finally:
        PETSc.Options().delValue("pc_gamg_agg_nsmooths")
    assert argv["solver"]["multigrid"]["options"] == {}
    assert argv["solver"]["iterations"] == mine["solver"]["iterations"]
    # smoothing changes the iterates: the two runs must differ
    assert mine["solver"]["iterations"] != res["solver"]["iterations"]


def test_a_whole_bed_records_unsmoothed_aggregation():
    bed = box_bed()
    res = homogenize_arrays(bed.centers, bed.radii, solver="gamg")
    assert res["solver"]["multigrid"]["options"] == {}
    assert "second-order" in res["solver"]["multigrid"]["reason"]
