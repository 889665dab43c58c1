"""The compiled continuation engine on a textbook fold: the Duffing oscillator's frequency response.

x'' + 2 zeta x' + x + gamma x^3 = F cos(w t) by one-harmonic balance, x = a cos(w t) + b sin(w t):

    R1 = (1 - w^2) a + 2 zeta w b + 3/4 gamma (a^2 + b^2) a - F = 0
    R2 = (1 - w^2) b - 2 zeta w a + 3/4 gamma (a^2 + b^2) b = 0

in p = w. A hardening spring (gamma > 0) bends the resonance to the right: the response curve has
two folds, between which three amplitudes coexist; every point satisfies the amplitude equation
[(1 - w^2 + 3/4 gamma A^2)^2 + (2 zeta w)^2] A^2 = F^2. The problem supplies only its residual and
Jacobian: the engine's dense corrector, tangent and fixed-p Newton do the rest.
"""
import math
import subprocess
import sys
from collections import namedtuple
from pathlib import Path

import numba
import numpy as np
import pytest

from dea_ros.solvers import arclength_kernels as engine, jit

Duffing = namedtuple("Duffing", ["zeta", "gamma", "force"])


@numba.njit
def duffing_residual_jacobian(problem, z, p):
    a, b = z[0], z[1]
    w, zeta, gamma = p, problem.zeta, problem.gamma
    amp2 = a * a + b * b
    k = 1.0 - w * w + 0.75 * gamma * amp2
    r = np.array([k * a + 2.0 * zeta * w * b - problem.force, k * b - 2.0 * zeta * w * a])
    jac = np.array([[k + 1.5 * gamma * a * a, 2.0 * zeta * w + 1.5 * gamma * a * b],
                    [-2.0 * zeta * w + 1.5 * gamma * a * b, k + 1.5 * gamma * b * b]])
    dr = np.array([-2.0 * w * a + 2.0 * zeta * b, -2.0 * w * b - 2.0 * zeta * a])
    return r, jac, dr


engine.register_problem(Duffing, duffing_residual_jacobian)
PROBLEM = Duffing(0.05, 1.0, 0.3)


def amplitude_equation(a, b, w, problem=PROBLEM):
    amp2 = a * a + b * b
    return ((1.0 - w * w + 0.75 * problem.gamma * amp2) ** 2 + (2.0 * problem.zeta * w) ** 2) * amp2 - \
        problem.force ** 2


def start(w0):
    z, _it, status = engine.solve_at(PROBLEM, np.array([0.4, 0.0]), w0, 1e-12, 50)
    assert status == 0
    t, ok = engine.tangent(PROBLEM, z, w0, np.zeros(2), 1.0, 1.0)
    assert ok
    norm = math.sqrt(t[0] ** 2 + t[1] ** 2 + t[2] ** 2)
    return z, t[:2] / norm, t[2] / norm


def test_the_engine_follows_the_duffing_response_through_both_folds():
    w_grid = np.linspace(0.5, 2.5, 41)
    z0, tz, tp = start(w_grid[0])
    status, p_end, steps, stopped, zs, _tzs, table, folds, g_z, g_table = engine.trace_branch(
        PROBLEM, z0, w_grid[0], tz, tp, w_grid[0] - 0.1, w_grid[-1], 5000, 0.01, 0.05, w_grid, 1.0, 1e-12)
    assert status == 0 and not stopped and p_end >= w_grid[-1]
    assert len(folds) == 2                                     # the two turning points of the hysteresis loop
    ws = table[:, engine.STEP_P]
    residuals = [amplitude_equation(z[0], z[1], w) for z, w in zip(zs, ws)]
    assert np.max(np.abs(residuals)) < 1e-9
    fold_w = sorted(ws[k] for k in folds)
    assert 1.2 < fold_w[0] < fold_w[1] < 2.5                   # the jump-down fold above the jump-up one
    # requested frequencies: solved exactly, three times inside the loop, once outside it
    grid_w = g_table[:, engine.GRID_P]
    assert set(np.round(grid_w, 12)) == set(np.round(w_grid[1:], 12))
    for z, w in zip(g_z, grid_w):
        assert abs(amplitude_equation(z[0], z[1], w)) < 1e-12
        n_solutions = np.count_nonzero(np.isclose(grid_w, w))
        assert n_solutions == (3 if fold_w[0] < w < fold_w[1] else 1)
    # the peak: the largest amplitude along the branch is at the upper fold (backbone 1 + 3/8 gamma A^2)
    amps = np.hypot(zs[:, 0], zs[:, 1])
    k = int(np.argmax(amps))
    assert ws[k] == pytest.approx(math.sqrt(1.0 + 0.75 * PROBLEM.gamma * amps[k] ** 2), rel=2e-2)


def test_the_engine_stops_after_max_steps():
    z0, tz, tp = start(0.5)
    status = engine.trace_branch(PROBLEM, z0, 0.5, tz, tp, 0.4, 2.5, 3, 0.01, 0.05, np.array([1.0]), 1.0, 1e-12)[0]
    assert status == engine.TRACE_MAX_STEPS


def test_a_problem_of_a_test_module_stays_out_of_the_kernel_cache():
    """numba pickles the argument types of every cached specialisation into one index per kernel: a problem
    type another process cannot import (this test module's) must never get there, or every process that
    loads the engine from the cache fails (it did: 'No module named test.solvers' in the nodes)."""
    z0, tz, tp = start(0.5)
    engine.trace_branch(PROBLEM, z0, 0.5, tz, tp, 0.4, 1.0, 50, 0.01, 0.05, np.array([0.7]), 1.0, 1e-12)
    for index in Path(jit.CACHE_DIR).rglob("*.nbi"):
        assert b"Duffing" not in index.read_bytes(), index
    out = subprocess.run([sys.executable, "-c", "import numpy as np; from dea_ros.model import preset; "
                          "from dea_ros.solvers import SinePeriodic, frequency_sweep; "
                          "frequency_sweep(preset('A2'), SinePeriodic(2500.0, 1.0), np.linspace(1.0, 3.0, 3), "
                          "n_harmonics=4)"], capture_output=True, text=True, timeout=1800)
    assert out.returncode == 0, out.stderr[-2000:]
