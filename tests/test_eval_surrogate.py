"""run/train/eval_surrogate.py's pure parts: the size-curve fit and the verdicts."""

import numpy as np
import pytest

from run.train import eval_surrogate as ev


def test_size_curve_recovers_a_power_law():
    sizes = [500, 1000, 2000, 4000]
    a = np.array([0.5, 0.4, 0.3, 0.6, 0.6, 0.9])
    p = np.array([0.2, 0.25, 0.3, 0.2, 0.22, 0.35])
    results = [{"t": {"all beds": {"mre": (a * n ** -p).tolist()}}} for n in sizes]
    fit = ev.size_curve(sizes, results, "t")
    for j, name in enumerate(fit):
        fa, fp, n_gate, n_goal = fit[name]
        assert fa == pytest.approx(a[j], rel=1e-9) and fp == pytest.approx(p[j], rel=1e-9)
        assert a[j] * n_gate ** -p[j] == pytest.approx(ev.GATE, rel=1e-9)
        assert a[j] * n_goal ** -p[j] == pytest.approx(ev.GOAL[j], rel=1e-9)


def test_verdicts():
    assert ev.verdict([0.019] * 3 + [0.029] * 3) == "goal"
    assert ev.verdict([0.021] * 3 + [0.029] * 3) == "gate"
    assert ev.verdict([0.01] * 5 + [0.04]) == "-"
