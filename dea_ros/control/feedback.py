"""Feedback on the measured displacement, acting on u^2, with gains derived from the identified model.

Structure (why PID on u^2 with model scaling): the input enters eq. 18 as ``b(d) u^2`` with
``b(d) = -(c1bar/m) c2 d`` (eqs. 6, 18), and the feedforward already cancels the nonlinear
stiffness along the reference. What remains for the feedback is the error dynamics of the model
linearised along the reference (eps1 frozen: the fast mechanical mode)::

    e'' + c e' + k e = -a_fb + (model error, noise, creep)      e = d_r - d

with the feedback written as an acceleration ``a_fb`` and applied as ``du^2 = a_fb / b(d_r)``.
A PID on e with a first-order derivative filter,
``a_fb = kp e + ki int(e) + kd D(e)``, ``D(s) = s / (1 + Tf s)``, gives the closed-loop
characteristic polynomial ``s^3 + (c + kd) s^2 + (k + kp) s + ki`` (Tf -> 0), and the gains follow by
pole placement at a triple real pole -p (no overshoot of the error dynamics)::

    kd = 3 p - c,   kp = 3 p^2 - k,   ki = p^3

where k, c are the identified model's stiffness and damping per unit mass at the operating point
(:meth:`ModelInverse.linearisation`). The only design choice is the bandwidth p, chosen by a stated
rule: the largest p (bisection) for which the loop ``L(s) = C(s) P(s) e^{-s tau} / b`` — P the full
3-state linearisation (creep included), tau the loop delay (sensor-to-amplifier latency plus half a
sample period for the zero-order hold) — keeps a phase margin >= ``phase_margin_deg`` (45 deg) and a
gain margin >= ``gain_margin`` (2); the derivative filter corner is ``filter_ratio`` (5) times the
crossover of the derivative term. The delay, not the model, limits the bandwidth: a PID cannot
cancel the lightly damped resonance (zeta ~ 0.01) without it, which is why the feedforward does the
tracking and the feedback only removes model error and disturbances.

Anti-windup: conditional integration (the integrator freezes while the command is saturated at
u^2 = 0, at the voltage limit or at the slew limit in the direction the error pushes).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .inverse import ModelInverse

__all__ = ["FeedbackGains", "design_gains", "loop_margins", "noise_gain", "PIDOnU2"]


@dataclass(frozen=True)
class FeedbackGains:
    """PID gains in acceleration units (a_fb = kp e + ki int e + kd De) and how they were derived."""

    kp_per_s2: float
    ki_per_s3: float
    kd_per_s: float
    derivative_filter_s: float
    damping_ratio: float             # zeta of the closed-loop mechanical mode
    integrator_pole_rad_per_s: float # p_i
    loop_delay_s: float              # tau used in the design
    operating_point_m: float
    stiffness_per_s2: float          # k of the linearisation
    damping_per_s: float             # c of the linearisation
    max_sensitivity: float           # achieved Ms = max |1/(1 + L)|
    noise_gain: float                # RMS position error per RMS sensor noise
    phase_margin_deg: float          # achieved
    gain_margin: float               # achieved
    crossover_rad_per_s: float

    def describe(self) -> str:
        return (f"closed-loop mode at the model's {math.sqrt(self.stiffness_per_s2) / (2 * math.pi):.2f} Hz with damping "
                f"{self.damping_ratio:.3f}, integrator pole -{self.integrator_pole_rad_per_s:.1f} rad/s "
                f"(model k = {self.stiffness_per_s2:.4g} 1/s^2, "
                f"c = {self.damping_per_s:.3g} 1/s at {self.operating_point_m * 1e6:.1f} um; loop delay "
                f"{self.loop_delay_s * 1e3:.2f} ms): kp = {self.kp_per_s2:.4g} 1/s^2, ki = {self.ki_per_s3:.4g} 1/s^3, "
                f"kd = {self.kd_per_s:.4g} 1/s, Tf = {self.derivative_filter_s * 1e3:.3f} ms; Ms {self.max_sensitivity:.2f}, "
                f"noise gain {self.noise_gain:.3f}, "
                f"phase margin "
                f"{self.phase_margin_deg:.1f} deg, gain margin {self.gain_margin:.2f}, crossover "
                f"{self.crossover_rad_per_s / (2 * math.pi):.1f} Hz")


def _plant_polynomials(inverse: ModelInverse, d_op: float):
    """Numerator/denominator (highest power first) of P(s)/b, the 3-state linearisation at rest at d_op."""
    from scipy.signal import ss2tf

    model = inverse.model
    J = np.array(model.jacobian_u2(d_op, inverse.relaxed_strain(d_op), 0.0, inverse.static_u2(d_op)), dtype=float)
    num, den = ss2tf(J, np.array([[0.0], [0.0], [1.0]]), np.array([[1.0, 0.0, 0.0]]), np.array([[0.0]]))
    return np.trim_zeros(np.atleast_1d(num[0]), "f"), den


def _pade3(tau):
    """(num, den) of the (3,3) Pade approximant of exp(-s tau)."""
    return (np.array([-tau ** 3 / 120, tau ** 2 / 10, -tau / 2, 1.0]),
            np.array([tau ** 3 / 120, tau ** 2 / 10, tau / 2, 1.0]))


def loop_margins(inverse: ModelInverse, d_op: float, kp, ki, kd, tf, delay_s, w=None):
    """Robustness of the loop L = C P e^{-s tau} at d_op.

    Returns a dict: ``stable`` (closed-loop poles with a (3,3) Pade delay all in the left half
    plane), ``max_sensitivity`` (Ms = max |1/(1 + L(jw))|, exact delay), ``phase_margin_deg`` and
    ``gain_margin`` (worst over all crossings), ``crossover_rad_per_s`` (highest gain crossover).
    """
    if w is None:
        w = np.logspace(-1, 4.5, 6000)
    numP, denP = _plant_polynomials(inverse, d_op)
    numD, denD = _pade3(delay_s) if delay_s > 0 else (np.array([1.0]), np.array([1.0]))
    numC = np.polyadd(np.polyadd(kp * np.array([tf, 1.0, 0.0]), ki * np.array([tf, 1.0])), kd * np.array([1.0, 0.0, 0.0]))
    denC = np.array([tf, 1.0, 0.0])
    char = np.polyadd(np.polymul(np.polymul(denC, denP), denD), np.polymul(np.polymul(numC, numP), numD))
    stable = bool(np.all(np.roots(char).real < 0.0))
    s = 1j * w
    L = _controller(kp, ki, kd, tf, s) * (np.polyval(numP, s) / np.polyval(denP, s)) * np.exp(-s * delay_s)
    ms = float(np.max(np.abs(1.0 / (1.0 + L))))
    mag = np.abs(L)
    phase = np.angle(L)                       # wrapped to (-pi, pi]
    pm, wc = math.inf, math.nan
    for i in np.nonzero((mag[:-1] - 1.0) * (mag[1:] - 1.0) <= 0.0)[0]:
        margin = 180.0 - abs(math.degrees(phase[i]))
        if margin < pm:
            pm = margin
        wc = float(w[i]) if math.isnan(wc) else max(wc, float(w[i]))
    gm = math.inf
    g = np.mod(phase, 2 * math.pi) - math.pi  # 0 where the phase is +-180 deg
    for i in np.nonzero(np.sign(g[:-1]) != np.sign(g[1:]))[0]:
        if abs(g[i] - g[i + 1]) < math.pi and mag[i] < 1.0:
            gm = min(gm, 1.0 / mag[i])
    return {"stable": stable, "max_sensitivity": ms, "phase_margin_deg": pm, "gain_margin": gm,
            "crossover_rad_per_s": wc}


def noise_gain(inverse: ModelInverse, d_op: float, kp, ki, kd, tf, delay_s, sample_period_s) -> float:
    """RMS of the true displacement per RMS of white measurement noise (|T(jw)|^2 averaged to Nyquist).

    ``T = L / (1 + L)`` carries the sensor noise into the position; white noise sampled every
    ``sample_period_s`` is spread evenly up to the Nyquist frequency pi / T.
    """
    wn = math.pi / sample_period_s
    w = np.linspace(wn / 20000.0, wn, 20000)
    numP, denP = _plant_polynomials(inverse, d_op)
    s = 1j * w
    L = _controller(kp, ki, kd, tf, s) * np.polyval(numP, s) / np.polyval(denP, s) * np.exp(-s * delay_s)
    t2 = np.abs(L / (1.0 + L)) ** 2
    return float(math.sqrt(np.sum(0.5 * (t2[1:] + t2[:-1]) * np.diff(w)) / wn))


def _controller(kp, ki, kd, tf, s):
    return kp + ki / s + kd * s / (1.0 + tf * s)


def design_gains(inverse: ModelInverse, operating_point_m: float, loop_delay_s: float,
                 sample_period_s: float = 1e-3, max_sensitivity: float = 1.6, max_noise_gain: float = 0.25,
                 integral_ratio: float = 0.5, filter_ratio: float = 5.0) -> FeedbackGains:
    """PID gains by pole placement on the identified model; the damping ratio by a stated rule.

    Closed-loop poles (eps1 frozen): the model's own natural frequency w_n = sqrt(k) with damping
    raised to zeta, and the integrator pole at ``integral_ratio * zeta * w_n``::

        (s^2 + 2 zeta w_n s + w_n^2)(s + p_i):  kd = 2 zeta w_n + p_i - c,  kp = 2 zeta w_n p_i,
                                                ki = w_n^2 p_i

    zeta is the largest value in [0.02, 1] for which the loop with the delay keeps the closed loop
    stable, ``Ms <= max_sensitivity`` and ``noise_gain <= max_noise_gain``; the derivative filter
    time constant is ``1 / (filter_ratio * kd)``. See the module docstring.
    """
    if not (loop_delay_s >= 0.0 and math.isfinite(loop_delay_s)):
        raise ValueError(f"loop_delay_s: must be >= 0 s, got {loop_delay_s}")
    k, c, _ = inverse.linearisation(operating_point_m)
    if k <= 0.0:
        raise ValueError(f"the model is statically unstable at {operating_point_m * 1e6:.1f} um (stiffness {k:.4g})")
    w_n = math.sqrt(k)

    def gains(zeta):
        p_i = integral_ratio * zeta * w_n
        kd = max(2.0 * zeta * w_n + p_i - c, 0.0)
        kp = 2.0 * zeta * w_n * p_i
        ki = w_n * w_n * p_i
        tf = 1.0 / (filter_ratio * max(kd, 1e-9))
        return kp, ki, kd, tf, p_i

    def evaluate(zeta):
        kp, ki, kd, tf, _ = gains(zeta)
        m = loop_margins(inverse, operating_point_m, kp, ki, kd, tf, loop_delay_s)
        m["noise_gain"] = noise_gain(inverse, operating_point_m, kp, ki, kd, tf, loop_delay_s, sample_period_s)
        ok = m["stable"] and m["max_sensitivity"] <= max_sensitivity and m["noise_gain"] <= max_noise_gain
        return ok, m

    grid = np.linspace(0.02, 1.0, 50)
    results = [evaluate(z) for z in grid]
    good = [i for i, (ok, _) in enumerate(results) if ok]
    if not good:
        raise ValueError(
            f"no damping ratio keeps the loop stable with max sensitivity <= {max_sensitivity} and noise gain "
            f"<= {max_noise_gain} for a loop delay of {loop_delay_s * 1e3:.2f} ms; reduce loop_delay_s"
        )
    i = good[-1]
    zeta, m = float(grid[i]), results[i][1]
    if i + 1 < grid.size:           # refine between the last good and the first bad grid point
        a, b = grid[i], grid[i + 1]
        for _ in range(12):
            mid = 0.5 * (a + b)
            ok, mm = evaluate(mid)
            if ok:
                zeta, m, a = float(mid), mm, mid
            else:
                b = mid
    kp, ki, kd, tf, p_i = gains(zeta)
    return FeedbackGains(kp, ki, kd, tf, zeta, p_i, float(loop_delay_s), float(operating_point_m), float(k), float(c),
                         m["max_sensitivity"], m["noise_gain"], m["phase_margin_deg"], m["gain_margin"],
                         m["crossover_rad_per_s"])


class PIDOnU2:
    """Discrete PID in acceleration units (backward Euler integral, filtered derivative of the error).

    ``update(e, dt)`` returns a_fb; the caller divides by b(d) and reports saturation with
    :meth:`saturated` so the integrator stops winding up.
    """

    def __init__(self, gains: FeedbackGains):
        self.gains = gains
        self.reset()

    def reset(self, integral: float = 0.0) -> None:
        self.integral = float(integral)     # int e dt, m s
        self.derivative = 0.0               # filtered de/dt, m/s
        self.last_error: float | None = None
        self._last_increment = 0.0
        self.saturation = 0                 # -1 low, +1 high, 0 none (of the previous output)

    def update(self, error_m: float, dt_s: float) -> float:
        g = self.gains
        if self.last_error is not None and dt_s > 0.0:
            # D(s) = s/(1 + Tf s), backward Euler
            a = g.derivative_filter_s / (g.derivative_filter_s + dt_s)
            self.derivative = a * self.derivative + (error_m - self.last_error) / (g.derivative_filter_s + dt_s)
            # conditional integration: not while saturated in the direction the error pushes
            if not (self.saturation > 0 and error_m > 0.0) and not (self.saturation < 0 and error_m < 0.0):
                self.integral += error_m * dt_s
        self.last_error = float(error_m)
        return g.kp_per_s2 * error_m + g.ki_per_s3 * self.integral + g.kd_per_s * self.derivative

    def saturated(self, direction: int) -> None:
        """+1: the command was cut at its upper bound, -1 at its lower bound, 0: not saturated."""
        self.saturation = int(direction)
