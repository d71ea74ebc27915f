"""KUBC's Bagi strain to second order on beds with free hull vertices (amfe.solvers.adjoint,
docs/model.md section 5, "Strain to second order"); both solve paths and the option's check
are in tests/test_correction.py.

References: the strain's own definition (bagi_strain), a direct solve (Cholesky, exact to
round-off) of the same frame, the one-at-a-time path and two ranks.
"""
import json
import subprocess
import sys

import numpy as np
from helpers import MPI_ENV, ROOT, homogenize_arrays
from test_correction import box_bed, error, errors_over_rtol, rnd, round_bed  # noqa: F401 (rnd: a fixture)

from amfe.model.averages import bagi_strain, hull_of, voigt_strain
from amfe.model.frame import build_frame
from amfe.model.kubc import kubc_groups
from amfe.solvers.correction import (
    CORRECTED_RTOL,
    STRAIN_ADJOINT_DEFAULT,
    free_hull_vertices,
    strain_loads,
    strain_weights,
)

FIRST_ORDER_RTOL = 1e-8  # the uncorrected default (--solver gamg)


def test_the_loads_are_the_strains_gradients():
    rng = np.random.default_rng(3)
    x, u = rng.normal(size=(300, 3)), rng.normal(size=(300, 6))
    fixed = rng.random((300, 6)) < 0.5
    hull = hull_of(x)
    g = strain_loads(*strain_weights(hull), fixed)
    assert g.shape == (6, 300, 6) and not g[:, fixed].any()
    # on the free DOFs the functional is the Voigt strain itself (engineering shears)
    free_u = np.where(fixed, 0.0, u)
    assert np.allclose(np.einsum("mnd,nd->m", g, free_u),
                       voigt_strain(bagi_strain(hull, free_u[:, :3])), rtol=1e-12, atol=1e-14)


def test_only_beds_with_free_hull_vertices_take_the_adjoint():
    bed = box_bed()
    frame = build_frame(bed.centers, bed.radii)
    assert free_hull_vertices(frame, kubc_groups(frame)).size == 0
    round_frame = build_frame(*round_bed())
    assert free_hull_vertices(round_frame, kubc_groups(round_frame)).size > 0


def test_a_decade_of_rtol_gains_two_of_accuracy(rnd):
    x, r, ref = rnd
    err = errors_over_rtol(x, r, ref, "amfe_strain_adjoint")
    for rtol in (1e-3, 1e-4, 1e-5):  # the adjoint removes the strain's first-order error
        assert err[rtol, "yes"] < 0.1 * err[rtol, "no"], err
    # second order: about two decades per decade (measured 7.6e-5, 4.4e-7, 6.2e-9)
    assert err[1e-4, "yes"] < 0.05 * err[1e-3, "yes"], err
    assert err[1e-5, "yes"] < 0.05 * err[1e-4, "yes"], err
    # first order without it (3.9e-4 -> 2.2e-5)
    assert err[1e-5, "no"] > 0.02 * err[1e-4, "no"], err


def test_the_default_follows_the_option(rnd):
    x, r, ref = rnd
    res = homogenize_arrays(x, r, solver="gamg")
    plain = homogenize_arrays(x, r, solver="gamg", ksp_options={"-amfe_strain_adjoint": "no"})
    assert plain["solver"]["rtol"] == FIRST_ORDER_RTOL
    assert "strain_correction" not in plain["solver"]
    assert error(plain, ref) < 1e-6
    if STRAIN_ADJOINT_DEFAULT == "yes":
        s = res["solver"]
        assert s["rtol"] == CORRECTED_RTOL and len(s["adjoint_iterations"]) == 6
        assert 0 < s["strain_correction"] < 1e-3
        assert error(res, ref) < 1e-6
    else:
        assert res["solver"]["rtol"] == FIRST_ORDER_RTOL


SCRIPT = r"""
import json, sys
sys.path.insert(0, "tests")
from amfe.solvers.petsc import init_petsc
PETSc = init_petsc()
from amfe.model.bed import Bed
from amfe.model.options import SolveOptions
from amfe.solvers.driver import homogenize_bed
from test_correction import round_bed
x, r = round_bed()
res = homogenize_bed(Bed(x, r), SolveOptions(solver="gamg", rtol=1e-5, ksp_options={
    "amfe_strain_adjoint": "yes"})).to_dict()
if PETSc.COMM_WORLD.getRank() == 0:
    print("RESULT " + json.dumps({"properties": res["properties"]}), flush=True)
"""


def test_two_ranks_take_the_same_adjoint(tmp_path, rnd):
    _, _, ref = rnd
    script = tmp_path / "adjoint.py"
    script.write_text(SCRIPT)
    proc = subprocess.run(["mpirun", "-n", "2", sys.executable, str(script)],
                          capture_output=True, text=True, cwd=ROOT, env=MPI_ENV, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads([s for s in proc.stdout.splitlines() if s.startswith("RESULT ")][0][7:])
    assert error(res, ref) < 1e-6
