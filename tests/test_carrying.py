"""What carries load under each condition, and V = the bed's box (docs/model.md, section 5):
hand-made beds of simple cubic blocks (spacing 1.8 r: bonds along the axes only)."""
import numpy as np
import pytest
from helpers import cubic_lattice, homogenize_arrays

from amfe.errors import AmfeError
from amfe.model.averages import box_center, unit_strains
from amfe.model.carrying import bed_box, removed_warning
from amfe.model.frame import build_frame
from amfe.model.kubc import boundary_particles, kubc_displacements
from amfe.model.subc import energy_gap, subc_weights
from amfe.solvers.scipy_direct import global_stiffness, kubc_stiffness_scipy

S, R = 1.8e-6, 1e-6


def block(n, origin=(0.0, 0.0, 0.0), m=None):
    """An n x n x m block of the cubic lattice (centres (k,3) [m])."""
    g = np.arange(n) * S
    h = np.arange(m or n) * S
    x = np.stack(np.meshgrid(g, g, h, indexing="ij"), -1).reshape(-1, 3)
    return x + np.asarray(origin)


def bed(*parts):
    x = np.vstack(parts)
    return x, np.full(len(x), R)


def props(res):
    return np.array(list(res["properties"].values()))


def piece_moments(frame):
    """KUBC reaction moments (6 cases, pieces, 3, 3) per kept piece, by SuperLU."""
    import scipy.sparse.linalg as spla
    K = global_stiffness(frame)
    x = frame.centers
    bnd = np.flatnonzero(boundary_particles(x, frame.radii))
    pres = (6 * bnd[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(K.shape[0]), pres)
    U = np.zeros((K.shape[0], 6))
    for k, eps in enumerate(unit_strains()):
        U[pres, k] = kubc_displacements(x[bnd], box_center(x), eps).ravel()
    U[free] = spla.spsolve(K[free][:, free].tocsc(), -(K[free][:, pres] @ U[pres]))
    F = (K @ U)[pres].reshape(len(bnd), 3, 6)
    arm = x[bnd] - box_center(x)
    parts = frame.parts[bnd]
    return np.array([[np.einsum("bi,bj->ij", F[parts == p, :, k], arm[parts == p])
                      for p in range(parts.max() + 1)] for k in range(6)])


# --------------------------------------------------------------------------- #
# two blocks: side by side, stacked, joined by a track
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("axis", [0, 2])
def test_two_separate_blocks_both_carry_under_kubc(axis):
    """Side by side in x (axis 0) or stacked in z (axis 2), 3 spacings apart: both blocks
    are held by their prescribed faces, both are kept, and by mirror symmetry each takes
    exactly half of every normal reaction moment."""
    shift = np.zeros(3)
    shift[axis] = 7 * S                               # 4 S of block + a 3 S gap
    x, r = bed(block(4), block(4, shift))
    fr = build_frame(x, r)
    assert fr.n_removed == 0 and fr.parts.max() == 1
    M = piece_moments(fr)                             # (6, 2, 3, 3)
    for k in range(3):
        total = M[k, :, k, k].sum()
        assert total > 0 and M[k, 0, k, k] == pytest.approx(total / 2, rel=1e-9)
    res = homogenize_arrays(x, r, rtol=1e-12)
    C_ref = kubc_stiffness_scipy(fr)[0] * fr.stress_scale
    assert np.abs(np.array(res["C"]) - C_ref).max() < 1e-8 * np.abs(C_ref).max()
    assert res["n_removed"] == 0 and res["removed"]["components"] == 0
    # V is the box of all the spheres, gap included
    assert res["volume"] == pytest.approx(np.prod(bed_box(x, r)[0]), rel=1e-12)
    assert res["warnings"] == []


@pytest.mark.parametrize("axis", [0, 2])
def test_two_separate_blocks_have_no_subc_load_path(axis):
    shift = np.zeros(3)
    shift[axis] = 7 * S
    x, r = bed(block(4), block(4, shift))
    with pytest.raises(AmfeError, match="no load path across the box.*misses the "
                       + ("\\+x" if axis == 0 else "\\+z")):
        homogenize_arrays(x, r, bc="subc")
    with pytest.raises(AmfeError, match="mixed conditions: the bed has 2 separate"):
        homogenize_arrays(x, r, bc="mixed")


def test_two_blocks_joined_by_a_track_are_one_frame_under_every_condition():
    """A single chain of particles along x bridges the 3 S gap: one piece, nothing removed,
    KUBC matches the direct solve and SUBC lies below it in energy."""
    track = np.array([[4 * S, S, S], [5 * S, S, S], [6 * S, S, S]])  # on the line y = z = S
    x, r = bed(block(4), track, block(4, (7 * S, 0, 0)))
    fr = build_frame(x, r)
    assert fr.n_removed == 0 and fr.parts.max() == 0
    kubc = homogenize_arrays(x, r, rtol=1e-12)
    subc = homogenize_arrays(x, r, bc="subc", rtol=1e-12)
    C_ref = kubc_stiffness_scipy(fr)[0] * fr.stress_scale
    assert np.abs(np.array(kubc["C"]) - C_ref).max() < 1e-8 * np.abs(C_ref).max()
    assert energy_gap(np.array(kubc["C"]), np.array(subc["C"])) >= -1e-9
    assert kubc["volume"] == subc["volume"] == pytest.approx(np.prod(bed_box(x, r)[0]))


# --------------------------------------------------------------------------- #
# floating pieces change nothing
# --------------------------------------------------------------------------- #
def holed_block(n=6):
    """An n^3 block without its central 2 x 2 x 2 particles."""
    x = block(n)
    idx = np.rint(x / S).astype(int)
    hole = np.all((idx >= n // 2 - 1) & (idx <= n // 2), axis=1)
    return x[~hole]


@pytest.mark.parametrize("bc", ["kubc", "subc", "mixed"])
def test_floating_cluster_inside_the_box_changes_no_constant(bc):
    """A bonded pair in the block's cavity: removed, the same V, the same constants."""
    pair = np.array([[2.05 * S, 2.5 * S, 2.5 * S], [2.95 * S, 2.5 * S, 2.5 * S]])
    x0, r0 = bed(holed_block())
    x, r = bed(holed_block(), pair)
    for size in (None, [6 * S] * 3):
        ref = homogenize_arrays(x0, r0, bc=bc, rtol=1e-12, size=size)
        res = homogenize_arrays(x, r, bc=bc, rtol=1e-12, size=size)
        assert res["volume"] == ref["volume"]
        assert np.allclose(props(res), props(ref), rtol=1e-12, atol=1e-12)
        removed = res["removed"]
        assert res["n_removed"] == 2 and removed["components"] == 1
        assert removed["largest"] == [{"particles": 2, "volume_share": pytest.approx(2 / len(x)),
                                       "touches_boundary": False}]
        assert res["warnings"] == []                  # 2 of 210 particles: under 1 %


def test_floating_cluster_beside_the_block_keeps_the_blocks_box_and_constants():
    """Outside the block (it widens the box of all centres), two particles off the bed: not
    held (one line), removed; the boundary set and V return to the block's own."""
    x0, r0 = bed(block(4))
    x, r = bed(block(4), [[9 * S, S, S], [9.9 * S, S, S]])
    ref, res = (homogenize_arrays(*b, rtol=1e-12) for b in ((x0, r0), (x, r)))
    assert res["volume"] == ref["volume"] and res["n_removed"] == 2
    assert np.allclose(props(res), props(ref), rtol=1e-12, atol=1e-12)
    assert res["removed"]["touching_boundary"] == 1
    # 2 of 66 particles: a warning names the share
    assert len(res["warnings"]) == 1 and "2 particles (3.0 %" in res["warnings"][0]


def test_one_block_with_the_box_volume_is_todays_value_rescaled():
    """The kept set is unchanged: today's constants (V = hull of the centres) times
    V_hull / V_box, exactly (moduli; the Poisson ratios do not move)."""
    n = 4
    x, r = bed(block(n))
    fr = build_frame(x, r)
    k_n = fr.k_n[0] * fr.force_scale / fr.length_scale
    V_hull, V_box = ((n - 1) * S) ** 3, ((n - 1) * S + 2 * R) ** 3
    res = homogenize_arrays(x, r, rtol=1e-12)
    assert res["properties"]["Ex"] == pytest.approx(k_n / S * n**2 / (n - 1) ** 2 * V_hull / V_box,
                                                    rel=1e-9)


# --------------------------------------------------------------------------- #
# what is not held; the recorded size
# --------------------------------------------------------------------------- #
def test_boundary_pieces_on_one_line_are_not_held():
    """A straight 3-particle piece on the -z face is prescribed at three collinear
    particles: it would turn about its line, so it is removed."""
    x0, r0 = bed(block(4))
    line = np.array([[0, -2 * S, 0], [0.9 * S, -2 * S, 0], [1.8 * S, -2 * S, 0]])
    x, r = bed(block(4), line)
    fr = build_frame(x, r)
    assert fr.n_removed == 3 and fr.removed["touching_boundary"] == 1
    bent = line.copy()
    bent[1, 2] = 0.6 * S             # 0.72 r off the line through all three: held
    fr = build_frame(*bed(block(4), bent))
    assert fr.n_removed == 0 and fr.parts.max() == 1
    with pytest.raises(AmfeError, match="no bonded piece of the bed is held"):
        build_frame(*bed([[0, 0, 0], [S, 0, 0]], [[0, 5 * S, 0], [S, 5 * S, 0]]))


def test_recorded_size_is_the_volume_where_it_holds_the_bed():
    """A size too small for the load-carrying centres (a bed edited after generation, e.g.
    two copies under one copy's attributes) gives way to the spheres' box, with a warning."""
    x, r = bed(block(4))
    res = homogenize_arrays(x, r, rtol=1e-12, size=[4 * S] * 3)
    assert res["volume"] == pytest.approx((4 * S) ** 3, rel=1e-14) and res["warnings"] == []
    res = homogenize_arrays(x, r, rtol=1e-12, size=[2 * S] * 3)
    assert res["volume"] == pytest.approx((3 * S + 2 * R) ** 3, rel=1e-12)
    assert len(res["warnings"]) == 1 and "exceeds it by up to 50 %" in res["warnings"][0]
    with pytest.raises(AmfeError, match="three positive lengths"):
        homogenize_arrays(x, r, size=[S, -S, S])


def test_subc_weights_balance_on_each_piece():
    """Weights with two pieces (a checkerboard split of a lattice): each piece's loads carry
    no net force or moment and measure its own volume; together they measure V."""
    x, r = cubic_lattice(5, S, R)
    parts = (np.rint(x / S).astype(int).sum(axis=1) % 2)
    V = 2.0e-16
    idx, a, _ = subc_weights(x, r, V, parts)
    arm = x[idx] - box_center(x)
    total = np.zeros((3, 3))
    for p in (0, 1):
        own = parts[idx] == p
        assert np.abs(a[own].sum(axis=0)).max() < 1e-12 * np.abs(a).max()
        M = arm[own].T @ a[own]
        assert np.abs(M - M[0, 0] * np.eye(3)).max() < 1e-12 * V and M[0, 0] > 0
        total += M
    assert np.abs(total - V * np.eye(3)).max() < 1e-12 * V


def test_removed_warning_threshold():
    rep = {"particles": 1, "particle_share": 0.01, "volume_share": 0.01, "components": 1,
           "touching_boundary": 0, "largest": [{"particles": 1}]}
    assert removed_warning(rep, "kubc") == []
    rep["particle_share"] = 0.0101
    assert "carry no load under kubc" in removed_warning(rep, "kubc")[0]


# --------------------------------------------------------------------------- #
# periodic: the pieces that wind round the torus
# --------------------------------------------------------------------------- #
def test_periodic_floating_pair_is_removed_and_changes_nothing():
    box = [6 * S] * 3
    pair = np.array([[2.05 * S, 2.5 * S, 2.5 * S], [2.95 * S, 2.5 * S, 2.5 * S]])
    ref = homogenize_arrays(*bed(holed_block() + 0.3e-6), bc="periodic", box=box, rtol=1e-12)
    res = homogenize_arrays(*bed(holed_block() + 0.3e-6, pair + 0.3e-6), bc="periodic", box=box,
                         rtol=1e-12)
    assert res["n_removed"] == 2 and res["volume"] == ref["volume"]
    assert np.allclose(props(res), props(ref), rtol=1e-10, atol=1e-12)


def test_periodic_pieces_winding_in_too_few_directions_are_refused():
    """A 4 x 4 x 4 slab in a box 8 S deep in y winds round x and z only (kept, but alone it
    carries nothing along y); a chain along x beside it winds once: a mechanism."""
    box = np.array([4 * S, 8 * S, 4 * S])
    slab = block(4) + 0.3e-6
    with pytest.raises(AmfeError, match="only 2 of 3 independent directions"):
        build_frame(*bed(slab), box=box)
    chain = np.array([[k * S, 5.5 * S, 2 * S] for k in range(4)]) + 0.3e-6
    with pytest.raises(AmfeError, match="winds round the torus in one direction only"):
        build_frame(*bed(slab, chain), box=box)


def test_rule1_factor_converts_a_rule1_modulus_exactly():
    """V_hull / V_box of the largest piece: a rule-1 (hull volume) KUBC modulus times it is
    the rule-2 one where the kept piece is the same (the surrogate's conversion)."""
    from amfe.dataset.parts import label_rule
    from amfe.model.carrying import rule1_factor
    n = 4
    x, r = bed(block(n), [[9 * S, S, S], [9.9 * S, S, S]])     # plus a removed pair
    hull = ((n - 1) * S) ** 3
    assert rule1_factor(x, r) == pytest.approx(hull / ((n - 1) * S + 2 * R) ** 3, rel=1e-12)
    assert rule1_factor(x, r, [11 * S] * 3) == pytest.approx(hull / (11 * S) ** 3, rel=1e-12)
    fr = build_frame(x, r, size=[11 * S] * 3)
    k_n = fr.k_n[0] * fr.force_scale / fr.length_scale
    res = homogenize_arrays(x, r, rtol=1e-12, size=[11 * S] * 3)
    rule1 = k_n / S * n**2 / (n - 1) ** 2                   # today's hull-volume value
    assert res["properties"]["Ex"] == pytest.approx(rule1 * rule1_factor(x, r, [11 * S] * 3),
                                                    rel=1e-9)
    assert label_rule({}) == 1 and label_rule({"format_version": 1}) == 1
    assert label_rule({"format_version": 2}) == 2


def test_cli_prints_the_removed_share_and_writes_the_pieces(tmp_path):
    import json

    from helpers import run_cli

    from amfe.io.bedfile import write_bed
    from amfe.model.bed import Bed
    x, r = bed(block(4), [[9 * S, S, S], [9.9 * S, S, S]])
    path = tmp_path / "bed.h5"
    write_bed(path, Bed(x, r, {}))
    out = tmp_path / "r.json"
    proc = run_cli(["homogenize", str(path), "-o", str(out), "--quiet"])
    assert proc.returncode == 0, proc.stderr
    assert "amfe: warning: 2 particles (3.0 %" in proc.stderr
    d = json.loads(out.read_text())
    assert d["removed"]["components"] == 1 and d["removed"]["largest"][0]["touches_boundary"]
    assert len(d["warnings"]) == 1 and "carry no load under kubc" in d["warnings"][0]


def test_two_interpenetrating_periodic_pieces_each_carry_with_their_own_pin():
    """Two 3D crosses of chains, the second shifted by half the box: separate pieces that
    each wind round x, y and z. Each is pinned on its own; the stiffness is twice one
    cross's (the same box, translation invariance)."""
    k = np.arange(8) * S
    z = np.zeros(8)
    cross = np.unique(np.vstack([np.c_[k, z, z], np.c_[z, k, z], np.c_[z, z, k]]), axis=0)
    box = [8 * S] * 3
    one = homogenize_arrays(*bed(cross + 0.3e-6), bc="periodic", box=box, rtol=1e-12)
    two = homogenize_arrays(*bed(cross + 0.3e-6, cross + 4 * S + 0.3e-6), bc="periodic", box=box,
                         rtol=1e-12)
    assert two["n_removed"] == 0 and one["n_removed"] == 0
    np.testing.assert_allclose(np.array(two["C"]), 2 * np.array(one["C"]),
                               rtol=0, atol=1e-9 * np.abs(one["C"]).max())


def test_energy_ordering_holds_where_kubc_keeps_a_piece_subc_does_not():
    """A bonded triangle in a pit open at the -z face: KUBC holds it (three prescribed
    particles off one line) and keeps it, SUBC does not load it (it reaches one face);
    e C_subc e <= e C_kubc e still (KUBC's extra piece only adds energy)."""
    x = block(6)
    idx = np.rint(x / S).astype(int)
    pit = ((idx[:, 0] >= 1) & (idx[:, 0] <= 4) & (idx[:, 1] >= 1) & (idx[:, 1] <= 4)
           & (idx[:, 2] <= 1))
    tri = np.array([[2, 2.1, 0], [3, 2.1, 0], [2.5, 2.966, 0]]) * S     # sides S, as the lattice
    x, r = bed(x[~pit], tri)
    kubc = homogenize_arrays(x, r, rtol=1e-12)
    subc = homogenize_arrays(x, r, bc="subc", rtol=1e-12)
    alone = homogenize_arrays(*bed(block(6)[~pit]), rtol=1e-12)
    assert kubc["n_removed"] == 0 and subc["n_removed"] == 3
    assert kubc["volume"] == subc["volume"] == alone["volume"]
    assert kubc["properties"]["Ex"] > alone["properties"]["Ex"]      # the triangle carries
    assert energy_gap(np.array(kubc["C"]), np.array(subc["C"])) >= -1e-9


@pytest.mark.mpi
@pytest.mark.parametrize("bc", ["kubc", "subc"])
def test_several_pieces_on_two_ranks_match_one(tmp_path, bc):
    """Two separate blocks under KUBC (two pieces), two joined by a track under SUBC:
    1 and 2 ranks agree to 1e-9 at rtol 1e-12."""
    import json

    from helpers import run_cli

    from amfe.io.bedfile import write_bed
    from amfe.model.bed import Bed
    if bc == "kubc":
        x, r = bed(block(4), block(4, (7 * S, 0, 0)))
    else:
        x, r = bed(block(4), block(4, (7 * S, 0, 0)), [[4 * S, S, S], [5 * S, S, S], [6 * S, S, S]])
    path = tmp_path / "bed.h5"
    write_bed(path, Bed(x, r, {}))
    C = []
    for ranks in (None, 2):
        out = tmp_path / f"r{ranks}.json"
        proc = run_cli(["homogenize", str(path), "--bc", bc, "--rtol", "1e-12", "--quiet",
                        "-o", str(out)], ranks=ranks)
        assert proc.returncode == 0, proc.stderr
        C.append(np.array(json.loads(out.read_text())["C"]))
    assert np.abs(C[0] - C[1]).max() < 1e-9 * np.abs(C[0]).max()
