"""One source for the springs (issue 44, item 2): the numba kernel of the bond image compiles
amfe.model.springs' own functions, so its springs are the numpy path's bit for bit, a second
spring model plugs in by one table entry, and an edited formula is never served stale from
numba's on-disk cache."""
import shutil
import subprocess
import sys

import numpy as np
import pytest

from amfe.dataset.bondimage import _compiled_sums, _numpy_sums
from amfe.model.bed import generate_bed
from amfe.model.material import Material
from amfe.model.springs import (
    SPRING_MODELS,
    SpringModel,
    _paper_parts,
    critical_a_star,
    paper_coefficients,
    paper_springs,
    spring_constants,
)

pytest.importorskip("numba")

MATERIALS = [Material(), Material(E=70e9, nu=0.33, psi=0.0), Material(E=3e9, nu=-0.2, psi=0.3),
             Material(E=110e9, nu=0.49, psi=0.12)]


@pytest.mark.parametrize("material", MATERIALS, ids=lambda m: f"nu{m.nu}-psi{m.psi}")
def test_compiled_springs_equal_numpy_bit_for_bit(material):
    from amfe.dataset._jit import compiled_springs
    rng = np.random.default_rng(7)
    crit = critical_a_star(material.nu, material.psi)
    s = np.concatenate([rng.uniform(1e-4, crit, 3000), [1e-3, 0.5, 0.98 * crit, crit - 1e-10]])
    R = rng.lognormal(np.log(8e-6), 0.6, s.size)
    a = s * R
    ref = spring_constants(a, R, material)
    compiled = compiled_springs("paper")
    coef = paper_coefficients(material)
    got = np.array([compiled(a[k], R[k], coef) for k in range(s.size)]).T
    for name, x, y in zip(("k_n", "k_t", "kappa_n", "kappa_t"), ref, got):
        assert np.all(np.isfinite(x)) and np.all(x > 0), name
        assert np.array_equal(x, y), (name, np.flatnonzero(x != y)[:5])


def test_kernel_sums_are_the_springs_k_n_times_length_squared():
    # one bond, in one cell: the kernel's sum is spring_constants' k_n L^2 to the last bit
    R, L = 10e-6, 18.5e-6   # a* = a / (R / 2) = 0.76
    c = np.array([[20e-6, 20e-6, 20e-6], [20e-6 + L, 20e-6, 20e-6]])
    r = np.array([R, R])
    box = (np.zeros(3), np.full(3, 60e-6), np.full(3, 60e-6), np.ones(3, np.int64))
    material = Material()
    sums = _compiled_sums(c, r, material, box)
    # contact_geometry's a and R_eff in its order of operations, and bond_springs' a = a* R_eff
    Ri = Rj = R
    heron = (((Ri + Rj - L) * (L + Ri - Rj)) * (L - Ri + Rj)) * (Ri + Rj + L)
    r_eff = Ri * Rj / (Ri + Rj)
    a_star = np.sqrt(heron) / (2.0 * L) / r_eff
    assert a_star * r_eff == pytest.approx(np.sqrt(R**2 - (L / 2) ** 2), rel=1e-12)
    k_n = spring_constants(np.array([a_star * r_eff]), np.array([r_eff]), material)[0][0]
    assert sums is not None and sums.shape == (1,) and sums[0] == k_n * (L * L)


def _twice_paper(a, R, coef):
    # a toy second model: the paper's springs doubled (exact in floats), through a helper
    k_n, k_t, kappa_n, kappa_t = paper_springs(a, R, coef)
    return 2.0 * k_n, 2.0 * k_t, 2.0 * kappa_n, 2.0 * kappa_t


def test_a_second_spring_model_is_one_table_entry(monkeypatch):
    monkeypatch.setitem(SPRING_MODELS, "twice", SpringModel(
        "twice", paper_coefficients, _twice_paper, (paper_springs, _paper_parts)))
    bed = generate_bed((0.3e-3, 0.3e-3, 0.2e-3), seed=4)
    box = (np.zeros(3), np.array([0.29e-3, 0.25e-3, 0.2e-3]), np.array([30e-6, 30e-6, 70e-6]))
    box = (*box, np.ceil((box[1] - box[0]) / box[2] - 1e-9).astype(np.int64))
    paper = _compiled_sums(bed.centers, bed.radii, bed.material(), box)
    twice = _compiled_sums(bed.centers, bed.radii, bed.material(), box, springs="twice")
    ref = _numpy_sums(bed.centers, bed.radii, bed.material(), box, None)
    assert np.array_equal(paper, ref) and ref.max() > 0
    assert np.array_equal(twice, 2.0 * ref)
    k = spring_constants(np.array([1e-6, 4e-6]), np.array([5e-6, 6e-6]), Material(), "twice")
    assert all(np.array_equal(x, 2.0 * y) for x, y in zip(
        k, spring_constants(np.array([1e-6, 4e-6]), np.array([5e-6, 6e-6]), Material())))


def test_an_unknown_spring_model_is_named():
    from amfe.errors import AmfeError
    with pytest.raises(AmfeError, match="unknown spring model 'continuum'; choose one of paper"):
        spring_constants(np.array([1e-6]), np.array([5e-6]), Material(), "continuum")
    with pytest.raises(AmfeError, match="unknown spring model"):
        _compiled_sums(np.zeros((2, 3)) + [[0, 0, 0], [1e-5, 0, 0]], np.full(2, 6e-6),
                       Material(), (np.zeros(3), np.full(3, 1e-4), np.full(3, 1e-4),
                                    np.ones(3, np.int64)), springs=["paper"])


_TOY = """
from amfe.model.material import Material
def coefficients(material):
    return (float(material.E),)
def springs(a, R, coef):
    return FACTOR * coef[0] * a, 0.0, 0.0, 0.0
"""

_RUN = """
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import toysprings
from amfe.model.material import Material
from amfe.model.springs import SPRING_MODELS, SpringModel
SPRING_MODELS["toy"] = SpringModel("toy", toysprings.coefficients, toysprings.springs)
from amfe.dataset.bondimage import _compiled_sums
from amfe.dataset._jit import bond_sums_for
c = np.array([[20e-6, 20e-6, 20e-6], [38.5e-6, 20e-6, 20e-6]])
box = (np.zeros(3), np.full(3, 60e-6), np.full(3, 60e-6), np.ones(3, np.int64))
sums = _compiled_sums(c, np.full(2, 10e-6), Material(E=1.0), box, springs="toy")
print(repr(float(sums[0])), sum(bond_sums_for("toy").stats.cache_hits.values()))
"""


def test_an_edited_formula_is_not_served_from_the_cache(tmp_path):
    # numba caches the kernel on disk keyed by _jit.py; the springs' source is in the key too:
    # the same formula is loaded from the cache, an edited one compiles afresh
    def run(factor):
        (tmp_path / "toysprings.py").write_text(_TOY.replace("FACTOR", factor))
        # "1.0" and "3.0" are the same size: rewritten within the same second, Python would
        # import the old toysprings from its .pyc (mtime and size match) and serve factor 1
        shutil.rmtree(tmp_path / "__pycache__", ignore_errors=True)
        out = subprocess.run([sys.executable, "-c", _RUN, str(tmp_path)], capture_output=True,
                             text=True, timeout=300, check=False)
        assert out.returncode == 0, out.stderr
        value, hits = out.stdout.split()
        return float(value), int(hits)

    one, _ = run("1.0")
    again, hits = run("1.0")
    three, _ = run("3.0")
    assert one > 0 and again == one and hits == 1   # the second run loaded the cached kernel
    assert three == 3.0 * one
