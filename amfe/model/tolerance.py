"""The loosest solver tolerance each command accepts, from the constants' error bound.

docs/model.md, section 5 ("The loosest rtol"). A CG solve stopped at a true relative
residual r = ||b - A x|| / ||b|| <= RESIDUAL_FACTOR x rtol gives constants whose
relative error is at most about A x rtol, A the amplification from the residual to
the reaction forces and the strain. A was measured up to 85 (the uncorrected stress
on `small` beds at rtol 1e-8: 4e-8 to 8.5e-7 from Cholesky; the voxel model and the
periodic condition stay below 5); :data:`AMPLIFICATION` rounds it up to 100. The
second-order averages make the error smaller (about (A rtol)^2 where they apply),
never larger, so the first-order bound is the one every bed meets, and

    loosest rtol = what the command promises of its constants / AMPLIFICATION.
"""
from amfe.errors import AmfeError

AMPLIFICATION = 100.0
"""Relative error of the constants per unit of rtol, at most (measured 85, above)."""

ACCURACY = {
    # a bed's constants: 1 %, below the spread between beds of a few per cent
    "homogenize": 1e-2,
    # the reference of a surrogate's error, which --check prints to 0.1 %
    "predict --check": 1e-3,
    # the labels' contract (docs/datasets.md, "Label contract")
    "dataset": 1e-5,
}
"""The relative error of the constants each command promises."""


def loosest_rtol(command):
    """The largest rtol ``command`` (a key of :data:`ACCURACY`) accepts."""
    return ACCURACY[command] / AMPLIFICATION


#: The initial guess of a solve that stops after 0 iterations must meet the contract at
#: the loosest rtol any command accepts (amfe.solvers.ksp.check_solution).
LOOSEST_RTOL = max(loosest_rtol(c) for c in ACCURACY)


def check_command_rtol(command, rtol, name):
    """AmfeError (one line, with the reason) if ``rtol`` (a float or None) is looser than
    :func:`loosest_rtol` of ``command`` and below 1; ``name``: how the user gave it (--rtol,
    -ksp_rtol). Not a number, or outside (0, 1): left to the range check, which names it."""
    if rtol is None:
        return
    limit = loosest_rtol(command)
    try:
        value = float(rtol)
    except (TypeError, ValueError):
        return   # not a number: the range check (check_rtol, -ksp_rtol's) says so
    if limit * (1 + 1e-9) < value < 1.0:   # 1 and above: the range check's "(0, 1)"
        raise AmfeError(
            f"{name} {value:g} is too loose for amfe {command}: the constants' relative "
            f"error is up to about {AMPLIFICATION:g} x rtol (docs/model.md, section 5) and "
            f"{command} promises {ACCURACY[command]:g}; give an rtol of at most {limit:g}")


def given_rtol(args, petsc_pairs):
    """[(name, value)]: the tolerances a command line gives, --rtol and -ksp_rtol."""
    out = [] if args is None else [("--rtol", args)]
    return out + [("-ksp_rtol", v) for n, v in petsc_pairs if n == "ksp_rtol"]
