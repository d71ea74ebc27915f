"""Physics upscaling's coarse solve (amfe.training.upscale): a box of anisotropic tiles under
KUBC, checked against exact fields, the Voigt and Reuss bounds, and mirror symmetry."""
import numpy as np
import pytest

from amfe.training.stiffness import transform_stiffness
from amfe.training.upscale import kubc_stiffness, strain_matrices, tiles_of

SIZE = (0.6e-3, 0.6e-3, 0.3e-3)


def iso(E, nu):
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[np.arange(3), np.arange(3)] += 2 * mu
    C[np.arange(3, 6), np.arange(3, 6)] = mu
    return C


def spd(rng):
    A = rng.normal(size=(6, 6))
    return 1e9 * (A @ A.T + 6 * np.eye(6))


def test_strain_matrices_give_an_affine_field_its_strain():
    """u = E x on the 8 nodes: every Gauss point's B u is E in Voigt (engineering shear)."""
    h = np.array([2.0, 3.0, 0.5])
    B, wdet = strain_matrices(h)
    x = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)]) * h
    E = np.array([[1.0, 0.2, 0.3], [0.2, -0.5, 0.7], [0.3, 0.7, 2.0]])
    voigt = [E[0, 0], E[1, 1], E[2, 2], 2 * E[1, 2], 2 * E[0, 2], 2 * E[0, 1]]
    assert np.allclose(B @ (x @ E.T).ravel(), voigt, atol=1e-12)
    assert wdet * 8 == pytest.approx(np.prod(h))


def test_one_tile_material_gives_its_own_stiffness():
    C = spd(np.random.default_rng(0))
    out = kubc_stiffness(np.broadcast_to(C, (3, 4, 6, 6)), SIZE, sub=(2, 2, 2))
    assert np.abs(out - C).max() < 1e-12 * np.abs(C).max()


def test_a_checkerboard_lies_between_the_bounds_and_is_symmetric():
    tiles = np.array([[iso(1e9 * (1 + 9 * ((i + j) % 2)), 0.3) for i in range(4)]
                      for j in range(4)])
    C = kubc_stiffness(tiles, SIZE, sub=(2, 2, 2))
    assert np.abs(C - C.T).max() < 1e-12 * np.abs(C).max()
    voigt = tiles.mean(axis=(0, 1))
    reuss = np.linalg.inv(np.linalg.inv(tiles).mean(axis=(0, 1)))
    assert np.linalg.eigvalsh(voigt - C).min() > -1e-6 * np.abs(C).max()
    assert np.linalg.eigvalsh(C - reuss).min() > 0
    assert C[0, 0] < 0.95 * voigt[0, 0]   # the free interior relaxes: strictly below Voigt


def test_one_element_high_is_the_tiles_mean():
    """With one hexahedron through the height every node is on the top or bottom face: the
    field is affine and C is the tiles' mean (why the coarse solve needs sub z >= 2)."""
    rng = np.random.default_rng(1)
    tiles = np.array([[spd(rng) for _ in range(3)] for _ in range(2)])
    assert np.allclose(kubc_stiffness(tiles, SIZE, sub=(2, 2, 1)), tiles.mean(axis=(0, 1)),
                       rtol=1e-12, atol=0)


@pytest.mark.parametrize("flip", ["x", "y"])
def test_mirrored_tiles_give_the_mirrored_stiffness(flip):
    rng = np.random.default_rng(2)
    tiles = np.array([[spd(rng) for _ in range(3)] for _ in range(3)])
    kw = {"flip_x": flip == "x", "flip_y": flip == "y"}
    axis = 1 if flip == "x" else 0   # columns run along x, rows along y
    mirrored = transform_stiffness(np.flip(tiles, axis=axis), **kw)
    C = kubc_stiffness(tiles, SIZE, sub=(2, 2, 2))
    assert np.allclose(kubc_stiffness(mirrored, SIZE, sub=(2, 2, 2)),
                       transform_stiffness(C, **kw), rtol=1e-10, atol=1e-6 * np.abs(C).max())


def test_tiles_of_cuts_rows_along_y_and_refuses_partial_tiles():
    images = np.arange(2 * 3 * 40 * 60).reshape(2, 3, 40, 60)
    t = tiles_of(images, 20)
    assert t.shape == (2, 2, 3, 3, 20, 20)
    assert np.array_equal(t[1, 1, 2], images[1, :, 20:40, 40:60])
    with pytest.raises(ValueError, match="whole tiles"):
        tiles_of(images[..., :50], 20)
