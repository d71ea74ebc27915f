"""The compiled imaging kernels (C: amfe/dataset/fill.c, amfe/model/pairs.c; numba:
amfe.dataset._jit) give the numpy path's images and bonds bit for bit: the same imaging,
so data sets rebuild identically whichever runs."""
import os
import subprocess
import sys

import numpy as np
import pytest

from amfe.dataset import images, pixelkernel
from amfe.dataset.bondimage import (
    _compiled_sums,
    _image_of,
    _lean_sums,
    _numpy_sums,
    bond_image,
)
from amfe.dataset.images import pixelate, pixelate_spheres
from amfe.dataset.pixelkernel import union_volumes, use_kernel, warm
from amfe.errors import AmfeError
from amfe.model import pairkernel
from amfe.model.bed import generate_bed
from amfe.model.bonds import find_bonds, find_pairs
from amfe.model.material import STEEL

pytest.importorskip("numba")
if pixelkernel._c_fill() is None or not pairkernel.available():
    pytest.skip("no C compiler: the C kernels cannot be built", allow_module_level=True)


@pytest.fixture(params=["c", "numba"])
def kernel(request, monkeypatch):
    """Each compiled union kernel in turn: C, then numba's (the C one switched off)."""
    if request.param == "numba":
        monkeypatch.setattr(pixelkernel, "_c_fill", lambda: None)
        warm()
    return request.param


def _kd_tree_only(monkeypatch):
    """find_pairs by its KD-tree (the C bond finder switched off)."""
    monkeypatch.setattr(pairkernel, "bonds", lambda *a: None)


def _grid(lo, hi, cell, spacing, t):
    n = int(np.ceil(cell[0] / spacing))
    ax = images._Axis(lo[0], hi[0], cell[0], n)
    ay = images._Axis(lo[1], hi[1], cell[1], int(np.ceil(cell[1] / spacing)))
    return ax, ay, images._layer_edges(lo[2], hi[2], t)


@pytest.mark.parametrize("rows", [1, 7, 10_000])
def test_union_volumes_equal_numpy_bit_for_bit(rows, kernel):
    # polydisperse overlapping spheres, some reaching out of the box on every side, a
    # box of partial cells and layers; ``rows`` sets the strips (1: a strip per sample row)
    rng = np.random.default_rng(5)
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([97e-6, 71e-6, 230e-6])
    n = 400
    c = rng.uniform(lo - 15e-6, hi + 15e-6, size=(n, 3))
    r = rng.lognormal(np.log(10e-6), 0.4, size=n)
    r[0], c[0] = 60e-6, [50e-6, 30e-6, 100e-6]     # one sphere larger than a cell
    cell, t = (30e-6, 30e-6), 100e-6
    ax, ay, z = _grid(lo, hi, cell, 2e-6, t)
    shape = (z.size - 1) * ay.n_cells * ax.n_cells
    ref, fast = np.zeros(shape), np.zeros(shape)
    grid = images._Strip(ax, ay, 0, ay.n_sub, z, t, lo[2], hi[2])
    images._union_numpy(ref, c, r, grid, rows)
    union_volumes(c, r, grid, rows, images._Q_LEVELS, fast)
    assert ref.max() > 0 and np.count_nonzero(ref) > shape // 2
    assert np.array_equal(ref, fast)          # float64 volumes, every bit


def test_pixelate_engines_equal_on_generated_bed(kernel):
    bed = generate_bed((0.35e-3, 0.28e-3, 0.27e-3), seed=11)
    a = pixelate(bed, engine="numpy")
    b = pixelate(bed, engine="compiled")
    assert a.shape == (3, 10, 12) and a.dtype == b.dtype == np.float32
    assert np.array_equal(a, b)
    # the default spacing and a coarse one, through pixelate_spheres directly
    for spacing in (None, 7e-6):
        a = pixelate_spheres(bed.centers, bed.radii, [0, 0, 0], bed.attrs["size"],
                             spacing=spacing, engine="numpy")
        b = pixelate_spheres(bed.centers, bed.radii, [0, 0, 0], bed.attrs["size"],
                             spacing=spacing, engine="compiled")
        assert np.array_equal(a, b)


def test_compiled_bonds_equal_find_bonds(monkeypatch):
    bed = generate_bed((0.3e-3, 0.3e-3, 0.2e-3), seed=4)
    fast = find_bonds(bed.centers, bed.radii)   # the C bond finder's pairs
    a = bond_image(bed, engine="compiled")      # and numba's sums of the springs
    box = (np.zeros(3), np.array([0.29e-3, 0.25e-3, 0.2e-3]), np.array([30e-6, 30e-6, 70e-6]))
    n = np.ceil((box[1] - box[0]) / box[2] - 1e-9).astype(np.int64)
    sums = _compiled_sums(bed.centers, bed.radii, bed.material(), (*box, n))
    lean = _lean_sums(bed.centers, bed.radii, bed.material(), (*box, n))   # C bonds, numpy k_n
    _kd_tree_only(monkeypatch)
    ref = find_bonds(bed.centers, bed.radii)
    assert len(ref) > 1000
    for k, v in ref.__dict__.items():
        assert np.array_equal(v, getattr(fast, k)), k
    assert np.array_equal(a, bond_image(bed, engine="numpy")) and a.max() > 0
    # the kernel's sums themselves (not a fallback to numpy), float64, on a box of partial cells
    ref = _numpy_sums(bed.centers, bed.radii, bed.material(), (*box, n), None)
    assert sums is not None and np.count_nonzero(ref) == ref.size and np.array_equal(ref, sums)
    assert lean is not None and np.array_equal(ref, lean)


def test_compiled_bonds_leave_coincident_centres_to_numpy_error(monkeypatch):
    bed = generate_bed((0.15e-3, 0.15e-3, 0.1e-3), seed=2)
    c = np.vstack([bed.centers, bed.centers[3]])
    r = np.append(bed.radii, bed.radii[3])
    assert pairkernel.bonds(c, r, 1e-9) is None     # the C finder steps aside
    with pytest.raises(AmfeError) as fast:
        find_bonds(c, r)
    _kd_tree_only(monkeypatch)
    with pytest.raises(AmfeError) as ref:
        find_bonds(c, r)
    assert "coincident" in str(fast.value) and str(fast.value) == str(ref.value)


def test_compiled_bonds_of_a_far_flung_bed_go_the_numpy_way():
    # two bonded pairs 1e8 radii apart: a dense cell table would hold ~1e23 cells (past int64)
    R, far = 10e-6, 1e3
    c = np.array([[0, 0, 0], [15e-6, 0, 0], [far, far, far], [far + 15e-6, far, far]])
    r = np.full(4, R)
    assert pairkernel.bonds(c, r, 1e-9) is None
    ref = find_bonds(c, r)
    assert len(ref) == 2 and ref.i.tolist() == [0, 2] and ref.j.tolist() == [1, 3]


def test_compiled_bond_finder_equals_find_pairs_on_polydisperse_spheres(monkeypatch):
    # lognormal radii (cells of 2 max R hold many small spheres), every pair of neighbouring
    # cells visited once, sorted in O(M): the KD-tree's bonds and contact_geometry's lengths,
    # every bit; a capacity too small for the bonds is doubled until they fit
    rng = np.random.default_rng(8)
    r = rng.lognormal(np.log(10e-6), 0.35, size=3000)
    c = rng.uniform(0.0, 0.4e-3, size=(3000, 3)) * [1.0, 1.0, 0.5]
    with monkeypatch.context() as m:
        _kd_tree_only(m)
        i, j = find_pairs(c, r)
    d = c[j] - c[i]   # contact_geometry's lengths, its expression (random spheres nest, which
    ref_length = np.sqrt(np.einsum("ij,ij->i", d, d))   # it refuses)
    assert pairkernel.einsum_order() is not None and i.size > 2000
    caps, real = [], pairkernel._kernel()

    def counted(*args):
        caps.append(args[5])
        return real(*args)

    monkeypatch.setattr(pairkernel, "_kernel", lambda: counted)
    for cap_of in (lambda n: 8 * n + 64, lambda n: 7):
        caps.clear()
        monkeypatch.setattr(pairkernel, "_first_cap", cap_of)
        fi, fj, length = pairkernel.bonds(c, r, 1e-9)
        assert np.array_equal(fi, i) and np.array_equal(fj, j)
        assert np.array_equal(length, ref_length)
    assert caps[0] == 7 and caps[-1] >= i.size and len(caps) > 3   # grown by doubling
    assert all(np.array_equal(a, b) for a, b in zip(find_pairs(c, r), (i, j)))


def test_einsum_order_is_numpys():
    # the order the kernel sums d.d in is the one numpy's einsum uses here, on other vectors
    d = np.random.default_rng(3).uniform(-1, 1, size=(5000, 3)) * [1.0, 1e-3, 1e3]
    s = d * d
    sums = ((s[:, 0] + s[:, 1]) + s[:, 2], (s[:, 0] + s[:, 2]) + s[:, 1],
            s[:, 0] + (s[:, 1] + s[:, 2]))
    assert np.array_equal(sums[pairkernel.einsum_order()], np.einsum("ij,ij->i", d, d))


def test_engine_choice(monkeypatch):
    assert use_kernel("numpy", True) is False
    # with C, auto takes it for every bed (it costs no start)
    assert use_kernel("auto", False) is True and use_kernel("compiled", False) is True
    # without: numba's, for a small bed only once it is loaded (its load costs ~0.3 s)
    monkeypatch.setattr(pixelkernel, "_c_fill", lambda: None)
    assert use_kernel("auto", False) is ("amfe.dataset._jit" in sys.modules)
    assert use_kernel("auto", True) is True and use_kernel("compiled", False) is True
    assert warm() and use_kernel("auto", False) is True
    bed = generate_bed((0.1e-3, 0.1e-3, 0.1e-3), seed=1)
    for call in (lambda: pixelate(bed, engine="fast"), lambda: bond_image(bed, engine=None)):
        with pytest.raises(AmfeError, match="engine must be"):
            call()


def test_compiled_bond_image_steps_aside_for_a_bond_the_numpy_path_refuses():
    # two spheres overlapping past the critical a*: the same error either way (numba's springs
    # or numpy's); with a cap, the numpy path (the only one that caps) gives the image
    from amfe.dataset.bondimage import bond_image_of
    R = 20e-6
    half = np.sqrt(1 - 0.498**2) * R                 # a* = 2 a / R = 0.996 > 0.9934
    c = np.array([[45e-6 - half, 45e-6, 50e-6], [45e-6 + half, 45e-6, 50e-6]])
    args = (c, np.full(2, R), STEEL, np.zeros(3), [90e-6, 90e-6, 100e-6])
    grid = (args[3], args[4], (30e-6, 30e-6), 100e-6)
    assert _lean_sums(*args[:3], (np.zeros(3), np.array(args[4]), np.array(
        [30e-6, 30e-6, 100e-6]), np.array([3, 3, 1]))) is None   # steps aside to name the bond
    errors = []
    for engine in ("numpy", "compiled", "auto"):
        with pytest.raises(AmfeError, match="a\\* >= ") as err:
            _image_of(*args[:3], grid, None, engine)
        errors.append(str(err.value))
    assert errors[0] == errors[1] == errors[2]
    capped = bond_image_of(*args, a_star_cap=0.9)
    assert np.array_equal(capped, _image_of(*args[:3], grid, 0.9, "compiled")) and capped.max() > 0


def test_auto_images_small_beds_without_importing_numba():
    # a `small` bed's imaging (what the shipped model reads) pays no numba import: the C
    # kernels image it, and the same bits as numpy's
    code = ("import sys\nimport numpy as np\nfrom amfe.model.bed import generate_bed\n"
            "from amfe.dataset.images import pixelate\n"
            "from amfe.dataset.bondimage import bond_image\n"
            "bed = generate_bed((0.3e-3, 0.3e-3, 0.2e-3), seed=1)\n"
            "a, b = pixelate(bed), bond_image(bed)\n"
            "print('numba' in sys.modules, np.array_equal(a, pixelate(bed, engine='numpy')),\n"
            "      np.array_equal(b, bond_image(bed, engine='numpy')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "True", "True"]


def test_native_library_builds_once_into_its_cache_and_steps_aside_without_a_compiler(
        tmp_path):
    # a fresh cache: the first process builds the kernel, the next loads the same file; a
    # machine without a compiler gets None (the callers take numba or numpy)
    code = ("import os\nfrom amfe.dataset import pixelkernel\n"
            "d = os.environ['AMFE_CACHE_DIR']\n"
            "print(pixelkernel._c_fill() is not None,\n"
            "      os.path.isdir(d) and sorted(os.listdir(d)))\n")
    env = {**os.environ, "AMFE_CACHE_DIR": str(tmp_path / "k")}
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           timeout=300, env=env) for _ in range(2)]
    assert all(r.returncode == 0 for r in runs), runs[0].stderr
    first, second = (r.stdout.split(maxsplit=1) for r in runs)
    assert first == second and first[0] == "True" and "fill-" in first[1]
    built = next((tmp_path / "k").iterdir())
    mtime = built.stat().st_mtime_ns
    subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=300, env=env)
    assert built.stat().st_mtime_ns == mtime   # loaded, not rebuilt
    no_cc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           timeout=300, env={**env, "CC": "/nonexistent/cc",
                                             "AMFE_CACHE_DIR": str(tmp_path / "none")})
    assert no_cc.returncode == 0 and no_cc.stdout.split() == ["False", "False"]
