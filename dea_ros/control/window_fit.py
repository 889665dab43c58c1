"""Windowed least squares of the membrane's drift: the recursive tracker's information, used at once.

:class:`~.tracking.ModelTracker` keeps the last ``window_s`` of samples (measured d, the voltage that
acted, saturation). :func:`fit_window` fits the same normalised force balance as the tracker's EKF
(eq. 5 with eqs. 6, 10-12; see :mod:`.tracking`) to the whole window at once::

    y(t) = theta_g G(t) + theta_h S(t) + theta_1 K(t; tau)      (all terms through the same low-pass)

For a fixed creep time the problem is linear in the three ratios, so the fit solves it exactly on a
grid of ln tau (the tracker's bounds) and refines the best grid point by a parabola. Why: after a
drift, the EKF with a prior, process noise and a residual weight set to keep the unchanged plant
quiet moves k1 and tau slowly (k1 +25 %: 1.05 after 14 s; eta1 x0.3: tau 0.67 after 14 s), while
the least squares on the same 10 s of data gives 1.26 and 0.30. Static and dynamic information are
separated by the fit itself: the rest periods at several operating points determine the gain and
the static stiffness (G and S differ along d), the creep transients after each move determine k1
(amplitude) and tau (decay).

Safety: each ratio comes with its standard error (the residual's scale, inflated by the samples
per low-pass correlation time); :class:`WindowFit` marks a ratio ``informative`` only when that
error is below the gate, and the tracker moves only informative ratios, by at most ``max_jump``,
inside the physical bounds (:meth:`.tracking.ModelTracker.absorb`). Without excitation K is ~0
and its error is huge: k1 and tau do not move. The creep time is informative only with k1: tau is
the decay of the K term, and when its amplitude is undetermined the curvature of the SSE in ln tau
measures how well some decay fits the noise, not the creep (issue 23, session 11: 8 s into a rest
at the lower feedback gains of max_noise_gain 0.2 a fit with k1 = -5 +- 0.54 had ln tau +- 0.055).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import bilinear, lfilter, lfilter_zi

__all__ = ["WindowFitConfig", "WindowFit", "fit_window"]


@dataclass(frozen=True)
class WindowFitConfig:
    """Settings of :func:`fit_window` (ratios relative to the identified model; ln tau ratio for tau)."""

    window_s: float = 10.0
    burn_in_s: float = 1.5            # the creep state starts relaxed: residuals from here on
    decimation: int = 10              # one residual every this many samples
    grid_points: int = 25             # ln tau grid over the tracker's bounds (refined by a parabola)
    max_gate_std: tuple = (0.004, 0.004, 0.03, 0.1)   # a ratio (ln tau) is informative below this error
    max_jump: tuple = (0.1, 0.1, 0.5, 1.5)            # largest move of an estimate per fit
    saturation_guard_s: float = 0.005  # residuals this close to a saturated sample are dropped
    correlation_factor: float = 4.0   # residual samples per independent one (the low-pass correlation)
    # the loop delay beyond the tracker's voltage_delay_samples: a grid of extra delays, fitted on all
    # samples (the moves carry the information); informative below the gate
    delay_grid_s: tuple = (-0.5e-3, 3.0e-3, 0.25e-3)
    max_delay_std_s: float = 0.2e-3


@dataclass(frozen=True)
class WindowFit:
    """The fitted ratios (gain, static, k1, ln tau), their standard errors and whether each is informative."""

    x: tuple
    std: tuple
    informative: tuple
    residual_rms: float       # normalised (stress scale of the tracker)
    points: int               # residuals used
    eps1_end: float           # the creep state at the window's end for the fitted tau
    extra_delay_s: float = 0.0        # loop delay beyond the tracker's assumed one (voltage_delay_samples)
    extra_delay_std_s: float = math.inf
    delay_informative: bool = False


def _lowpass_filters(w: float, dt: float):
    """Digital (bilinear) low-pass w^2/(s+w)^2 and its first and second derivatives."""
    den = [1.0, 2.0 * w, w * w]
    return [bilinear(num, den, 1.0 / dt) for num in ([w * w], [w * w, 0.0], [w * w, 0.0, 0.0])]


def _filt(ba, x):
    b, a = ba
    return lfilter(b, a, x, zi=lfilter_zi(b, a) * x[0])[0]


def _creep(f, a):
    """eps1 along f = lambda_r - 1 for one creep factor a = exp(-dt/tau), starting relaxed."""
    return lfilter([1.0 - a], [1.0, -a], f, zi=[a * f[0]])[0]


def fit_window(model, scale_Pa: float, tau0_s: float, d_m, u_V, saturated, dt_s: float, filter_Hz: float,
               bounds, max_acceleration: float, config: WindowFitConfig | None = None) -> WindowFit | None:
    """The least squares of the drift over one window (see the module docstring); None if too few points."""
    cfg = config or WindowFitConfig()
    d = np.asarray(d_m, float)
    u = np.asarray(u_V, float)
    n = d.size
    if n < int((cfg.burn_in_s + 1.0) / dt_s):
        return None
    s = 1.0 + d * d / model.l0_sq
    lam = np.sqrt(s)
    lp, d1, d2 = _lowpass_filters(2.0 * math.pi * filter_Hz, dt_s)
    df, vf, af = _filt(lp, d), _filt(d1, d), _filt(d2, d)
    sf = 1.0 + df * df / model.l0_sq
    phi = df / (model.l0_sq * np.sqrt(sf))
    y = (_filt(lp, model.g * s / (model.force_gain * d)) - af * sf / (model.force_gain * df)
         - model.eta2 * phi * vf) / scale_Pa
    G = _filt(lp, model.c2 * s * u * u) / scale_Pa
    S = _filt(lp, model.hyperelastic_stress(s)) / scale_Pa
    use = np.zeros(n, bool)
    use[int(cfg.burn_in_s / dt_s)::max(int(cfg.decimation), 1)] = True
    use &= np.abs(af) < max_acceleration
    sat = np.asarray(saturated, bool)
    if sat.any():
        guard = max(int(cfg.saturation_guard_s / dt_s), 1)
        use &= np.convolve(sat.astype(float), np.ones(2 * guard + 1), mode="same") == 0.0
    m = int(use.sum())
    if m < 20:
        return None
    f = lam - 1.0
    grid = np.linspace(bounds[3][0], bounds[3][1], int(cfg.grid_points))
    sse = np.empty(grid.size)
    for j, z in enumerate(grid):
        sse[j] = _solve(y, G, S, _k_term(model, f, tau0_s * math.exp(z), dt_s, lp, scale_Pa), use)[1]
    j = int(np.argmin(sse))
    z = float(grid[j])
    curv = 0.0
    if 0 < j < grid.size - 1:
        h = grid[1] - grid[0]
        curv = (sse[j - 1] - 2.0 * sse[j] + sse[j + 1]) / (h * h)
        if curv > 0.0:
            z = float(np.clip(z - 0.5 * (sse[j + 1] - sse[j - 1]) / (h * curv), grid[j - 1], grid[j + 1]))
    tau = tau0_s * math.exp(z)
    K = _k_term(model, f, tau, dt_s, lp, scale_Pa)
    theta, sse_z, cov = _solve(y, G, S, K, use)
    var = sse_z / max(m - 4, 1) * cfg.correlation_factor
    std = [math.sqrt(max(c, 0.0) * var) if math.isfinite(c) else math.inf for c in np.diag(cov)]
    std.append(math.sqrt(2.0 * var / curv) if curv > 0.0 else math.inf)   # SSE(z) ~ SSE0 + curv/2 (z - z0)^2
    x = (float(theta[0]), float(theta[1]), float(theta[2]), z)
    informative = [bool(sd < gate) and math.isfinite(v) for sd, gate, v in zip(std, cfg.max_gate_std, x)]
    informative[3] = informative[3] and informative[2]     # a decay time needs its amplitude: no creep, no tau
    informative = tuple(informative)
    a = math.exp(-dt_s / tau)
    moves = use | (np.abs(af) >= max_acceleration)
    moves[:int(cfg.burn_in_s / dt_s)] = False
    delay, delay_std = _fit_delay(y, S, K, model.c2 * s, u, lp, scale_Pa, moves, dt_s, cfg)
    return WindowFit(x, tuple(std), informative, math.sqrt(sse_z / m), m, float(_creep(f, a)[-1]),
                     delay, delay_std, bool(delay_std < cfg.max_delay_std_s))


def _fit_delay(y, S, K, c2s, u, lp, scale_Pa, use, dt_s, cfg):
    """(extra delay s, its standard error s): the electrostatic term with the voltage shifted on a grid.

    The moves (where the quasi-static fit does not look) carry the timing: a voltage applied later
    than assumed shows as a residual during every move. The ratios are refitted at each delay.
    """
    lo, hi, step = cfg.delay_grid_s
    grid = np.arange(lo, hi + 0.5 * step, step)
    k = np.arange(u.size, dtype=float)
    sse = np.array([_solve(y, _filt(lp, c2s * np.interp(k - delay / dt_s, k, u) ** 2) / scale_Pa, S, K, use)[1]
                    for delay in grid])
    j = int(np.argmin(sse))
    if not 0 < j < grid.size - 1:
        return float(grid[j]), math.inf
    curv = (sse[j - 1] - 2.0 * sse[j] + sse[j + 1]) / (step * step)
    if curv <= 0.0:
        return float(grid[j]), math.inf
    delay = float(np.clip(grid[j] - 0.5 * (sse[j + 1] - sse[j - 1]) / (step * curv), grid[j - 1], grid[j + 1]))
    var = sse[j] / max(int(use.sum()) - 4, 1) * cfg.correlation_factor
    return delay, math.sqrt(2.0 * var / curv)


def _k_term(model, f, tau_s, dt_s, lp, scale_Pa):
    return _filt(lp, model.k1 * (f - _creep(f, math.exp(-dt_s / tau_s)))) / scale_Pa


def _solve(y, G, S, K, use):
    """theta, SSE and (H^T H)^-1 of y ~ [G S K] theta over the used samples."""
    H = np.column_stack((G[use], S[use], K[use]))
    yy = y[use]
    norms = np.sqrt(np.sum(H * H, axis=0))
    cols = [i for i in range(3) if norms[i] > 1e-9 * max(norms.max(), 1e-300)]
    Hn = H[:, cols] / norms[cols]
    cov = np.full((3, 3), np.inf)
    theta = np.ones(3)
    if cols and np.linalg.cond(Hn.T @ Hn) < 1e12:     # a column without excitation: that ratio stays unknown
        ci = np.linalg.inv(Hn.T @ Hn) / np.outer(norms[cols], norms[cols])
        theta[cols] = ci @ (H[:, cols].T @ yy)
        cov[np.ix_(cols, cols)] = ci
    r = yy - H @ theta
    return theta, float(r @ r), cov
