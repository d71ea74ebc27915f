"""The full-stiffness head: C SPD by construction, the nine constants from it, and the mirror
maps checked against the 4th-order tensor rotated by the 3x3 reflection."""
import itertools

import numpy as np
import pytest
import torch

from amfe.training.stiffness import (
    EIG_FLOOR,
    NINE,
    augment_stiffness,
    constants_from_stiffness,
    predict_stiffness,
    stiffness_from_raw,
    transform_stiffness,
    voigt_map,
)

VOIGT = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]


def to_tensor(C):
    """The 4th-order stiffness C_ijkl (3, 3, 3, 3) of a Voigt stiffness (6, 6)."""
    T = np.zeros((3, 3, 3, 3))
    for I, (i, j) in enumerate(VOIGT):
        for J, (k, l) in enumerate(VOIGT):
            for a, b in {(i, j), (j, i)}:
                for c, d in {(k, l), (l, k)}:
                    T[a, b, c, d] = C[I, J]
    return T


def to_voigt(T):
    return np.array([[T[i, j, k, l] for k, l in VOIGT] for i, j in VOIGT])


def rotate(C, R):
    """R C R^T computed on the tensor: C'_ijkl = R_ia R_jb R_kc R_ld C_abcd."""
    return to_voigt(np.einsum("ia,jb,kc,ld,abcd->ijkl", R, R, R, R, to_tensor(C)))


REFLECTIONS = {  # (flip_x, flip_y, transpose) -> the 3x3 map of coordinates
    (True, False, False): np.diag([-1.0, 1, 1]),
    (False, True, False): np.diag([1.0, -1, 1]),
    (False, False, True): np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, 1]]),
}


def random_spd(rng):
    A = rng.normal(size=(6, 6))
    return A @ A.T + 6 * np.eye(6)


def test_predicted_stiffness_is_spd_on_random_inputs():
    torch.manual_seed(0)
    # Raw outputs of a network's scale (normalised unit), and three times larger.
    raw = torch.cat([torch.randn(200, 21, dtype=torch.float64),
                     3 * torch.randn(200, 21, dtype=torch.float64)])
    C = stiffness_from_raw(raw).numpy()
    np.testing.assert_array_equal(C, np.swapaxes(C, 1, 2))
    assert np.linalg.eigvalsh(C).min() > 0.5 * EIG_FLOOR
    # An unconstrained symmetric matrix of the same entries is often not SPD: the head matters.
    tri = np.zeros((400, 6, 6))
    tri[:, *np.tril_indices(6)] = raw.numpy()
    plain = tri + np.swapaxes(tri, 1, 2)
    assert (np.linalg.eigvalsh(plain).min(axis=1) < 0).mean() > 0.5
    # The nine constants exist for every one (compliance_and_constants checks SPD).
    assert np.isfinite(constants_from_stiffness(C)).all()


def test_constants_of_an_isotropic_stiffness():
    E, nu = 2.0e9, 0.25
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[range(3), range(3)] += 2 * mu
    C[range(3, 6), range(3, 6)] = mu
    got = dict(zip(NINE, constants_from_stiffness(C)[0]))
    for k in ("Ex", "Ey", "Ez"):
        assert got[k] == pytest.approx(E, rel=1e-12)
    for k in ("nu_yz", "nu_xz", "nu_xy"):
        assert got[k] == pytest.approx(nu, rel=1e-12)
    for k in ("G_yz", "G_xz", "G_xy"):
        assert got[k] == pytest.approx(mu, rel=1e-12)


@pytest.mark.parametrize("sym", list(REFLECTIONS))
def test_mirror_map_is_the_reflected_tensor_and_an_involution(sym):
    rng = np.random.default_rng(1)
    C = random_spd(rng)
    want = rotate(C, REFLECTIONS[sym])
    np.testing.assert_allclose(transform_stiffness(C, *sym), want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(transform_stiffness(transform_stiffness(C, *sym), *sym), C,
                               rtol=0, atol=1e-12)


def test_mirror_in_x_flips_exactly_the_issues_entries():
    C = np.arange(1.0, 37.0).reshape(6, 6)
    C = C + C.T
    flipped = {(i - 1, j - 1) for i in range(1, 5) for j in (5, 6)}
    flipped |= {(j, i) for i, j in flipped}
    got = transform_stiffness(C, flip_x=True)
    for i, j in itertools.product(range(6), range(6)):
        assert got[i, j] == (-C[i, j] if (i, j) in flipped else C[i, j])


def test_combined_maps_compose_in_flip_images_order():
    """flip_x + flip_y + transpose is the product of the three reflections (mirrors first)."""
    rng = np.random.default_rng(2)
    C = random_spd(rng)
    R = REFLECTIONS[(False, False, True)] @ REFLECTIONS[(False, True, False)] \
        @ REFLECTIONS[(True, False, False)]
    np.testing.assert_allclose(transform_stiffness(C, True, True, True), rotate(C, R), atol=1e-12)
    M = voigt_map(True, True, True)
    np.testing.assert_allclose(M @ M.T, np.eye(6), atol=0)


def test_tta_stiffness_of_a_mirrored_image_is_the_mirrored_stiffness():
    """Averaged over the 8 symmetries as a tensor, the prediction is exactly equivariant."""
    from amfe.training.anysize import AnySizeNet
    from amfe.training.data import flip_images
    torch.manual_seed(3)
    net = AnySizeNet(2, channels=(4, 8), hidden=(16,)).double()
    x = torch.rand(3, 2, 6, 6, dtype=torch.float64)
    sizes = torch.full((3, 2), 0.18, dtype=torch.float64)
    base = predict_stiffness(net, x, sizes, tta="d4")
    for sym in REFLECTIONS:
        got = predict_stiffness(net, flip_images(x, *sym), sizes, tta="d4")
        np.testing.assert_allclose(got, transform_stiffness(base, *sym), rtol=1e-9, atol=1e-12)
    # Without averaging the network alone is not equivariant: the test can fail.
    plain = predict_stiffness(net, x, sizes)
    mirrored = predict_stiffness(net, flip_images(x, True), sizes)
    assert np.abs(mirrored - transform_stiffness(plain, True)).max() > 1e-6


def test_augmentation_moves_images_and_stiffness_together():
    from amfe.training.data import flip_images
    g = torch.Generator().manual_seed(4)
    x = torch.rand(16, 1, 4, 4, dtype=torch.float64)
    C = torch.as_tensor(np.stack([random_spd(np.random.default_rng(k)) for k in range(16)]))
    xa, Ca = augment_stiffness(x, C, g)
    changed = 0
    for k in range(16):
        match = [s for s in itertools.product([False, True], repeat=3)
                 if torch.equal(flip_images(x[k:k + 1], *s), xa[k:k + 1])]
        assert any(np.allclose(transform_stiffness(C[k].numpy(), *s), Ca[k].numpy())
                   for s in match)
        changed += not torch.equal(Ca[k], C[k])
    assert changed > 0
