"""Online model tracking: the drift of the membrane from the running data (applied voltage, measured d).

Four numbers, relative to the identified model, are tracked by an extended Kalman filter on the
force balance on the mass (eq. 5 with eqs. 6, 10-12, the third row of eq. 18)::

    m (g - a) s / (c1bar d) - eta2 phi(d) v = theta_g c2 s u^2 + theta_h sigma_h(s) + theta_1 k1 (lambda_r - 1 - eps1)
    eps1' = (lambda_r - 1 - eps1) / tau                                          (eq. 11, tau = eta1/k1)

* ``theta_g``: the electrostatic gain (eps_r, eq. 6; also a thickness change z0^-2);
* ``theta_h``: the hyperelastic stress (eq. 10), i.e. the static stiffness around the operating
  point (at rest eps1 = lambda_r - 1 and only sigma_h and the Maxwell stress hold the mass);
* ``theta_1``: the viscoelastic stiffness k1 (the short-time stiffness above the static one);
* ``tau``: the creep time eta1/k1, tracked as ln(tau / tau_identified).

d and u^2 pass through the same second-order low-pass (``filter_Hz``, default 4 Hz: well below the
membrane's mechanical mode, so the filtered d, d', d'' are clean and the inertia and damping terms
small), then every ``update_period_s`` the filter compares the measured left side with the model's
right side. It is safe under poor excitation by construction:

* a Kalman update moves the estimate only along the directions the data excite (a constant d and u
  determine one combination: the others do not move, "no drift without information"), and the
  random-walk process noise that lets it follow a drift raises the covariance only up to a cap;
* every update is bounded (``max_step``: at most this change of a ratio, or of ln tau, per update)
  and the estimate is clipped into physical bounds (``bounds``);
* updates are skipped while the command is saturated or the filtered acceleration is large (the
  quasi-static regression would be biased), and their residuals are normalised by a stress scale.

:meth:`ModelTracker.tracked_parameters` gives the tracked membrane as :class:`MembraneParameters`
(eps_r x theta_g, beta and gamma x theta_h, k1 x theta_1, eta1 = tau k1), which the controller's
feedforward and gain design use (:func:`dea_ros.control.adaptive.retune`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..model import DEAModel, MembraneParameters
from .window_fit import WindowFit, WindowFitConfig, fit_window

__all__ = ["TrackerConfig", "TrackedModel", "ModelTracker"]

NAMES = ("electrostatic_gain", "static_stiffness", "viscoelastic_stiffness", "creep_time")


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of :class:`ModelTracker` (SI units; ratios relative to the identified model)."""

    sample_period_s: float = 1e-3
    update_period_s: float = 0.01
    filter_Hz: float = 4.0
    # relative residual noise (of the normalised force balance) and random-walk drift per second
    residual_std: float = 2e-3
    drift_per_s: tuple = (6e-3, 6e-3, 6e-3, 2e-2)
    initial_std: tuple = (0.03, 0.03, 0.1, 0.3)
    max_std: tuple = (0.2, 0.2, 0.5, 1.0)
    max_step: float = 2e-3
    bounds: tuple = ((0.5, 1.5), (0.5, 1.5), (0.3, 3.0), (math.log(0.05), math.log(20.0)))
    max_filtered_acceleration_m_per_s2: float = 0.05
    # the command acts on the membrane this many samples after it is computed (latency + amplifier update)
    voltage_delay_samples: int = 1
    # the windowed least squares (window_fit.py) run at each retune; None: the EKF alone
    window: WindowFitConfig | None = WindowFitConfig()


@dataclass
class TrackedModel:
    """The tracked ratios (1 = the identified model), their standard deviations and the data used."""

    ratios: dict
    std: dict
    updates: int
    skipped: int
    excitation: float            # RMS of the normalised change of the regressors over the last second
    residual_rms: float          # RMS of the normalised residual over the last second
    extra: dict = field(default_factory=dict)


class _Filter:
    """Critically damped second-order low-pass x'' = w^2 (in - x) - 2 w x' (semi-implicit Euler)."""

    def __init__(self, w: float, dt: float, x0: float):
        self.w, self.dt = w, dt
        self.x, self.v, self.a = x0, 0.0, 0.0

    def step(self, value: float) -> None:
        w = self.w
        self.a = w * w * (value - self.x) - 2.0 * w * self.v
        self.v += self.dt * self.a
        self.x += self.dt * self.v


class ModelTracker:
    """Recursive estimator of the membrane's drift; one :meth:`update` per laser sample (no ROS)."""

    def __init__(self, params: MembraneParameters, config: TrackerConfig | None = None):
        self.params = params
        self.config = cfg = config or TrackerConfig()
        self.model = DEAModel.from_parameters(params)
        self.tau0_s = params.eta1_Pa_s / params.k1_Pa
        self.x = np.array([1.0, 1.0, 1.0, 0.0])                 # theta_g, theta_h, theta_1, ln(tau/tau0)
        self.P = np.diag(np.square(cfg.initial_std))
        self.Q = np.diag(np.square(cfg.drift_per_s) * cfg.update_period_s)
        self.P_max = np.square(np.asarray(cfg.max_std, float))
        self.lo = np.array([b[0] for b in cfg.bounds])
        self.hi = np.array([b[1] for b in cfg.bounds])
        self.every = max(int(round(cfg.update_period_s / cfg.sample_period_s)), 1)
        self.fd = None
        self.terms = []
        self.eps1 = self.psi = 0.0
        self.k = 0
        self.updates = self.skipped = 0
        self._last_h = None
        self._excitation = 0.0
        self._residual = 0.0
        self.scale = max(abs(params.k1_Pa) * 0.05, 1.0)       # stress scale of the residual, Pa
        self.enabled = True
        self._u_queue = [math.nan] * cfg.voltage_delay_samples
        n = int(round(cfg.window.window_s / cfg.sample_period_s)) if cfg.window is not None else 0
        self._buffer = np.zeros((3, n))          # d (m), applied voltage (V), saturated: the last window_s
        self._count = 0
        self.fits = 0
        self.extra_delay_s = 0.0                 # loop delay beyond voltage_delay_samples (window fit)

    # ------------------------------------------------------------- per sample
    def update(self, measured_m: float, voltage_V: float, saturated: bool = False) -> None:
        """One laser sample: the measured displacement (m) and the voltage applied meanwhile (V)."""
        if not (math.isfinite(measured_m) and math.isfinite(voltage_V)) or measured_m <= 0.0:
            return
        cfg = self.config
        if self._u_queue:            # the voltage acting on the membrane now: the command of a sample ago
            self._u_queue.append(float(voltage_V))
            voltage_V = self._u_queue.pop(0)
            if math.isnan(voltage_V):
                voltage_V = self._u_queue[-1]
        m = self.model
        d = float(measured_m)
        s = 1.0 + d * d / m.l0_sq
        lam = math.sqrt(s)
        if self.fd is None:
            w = 2.0 * math.pi * cfg.filter_Hz
            self.eps1 = lam - 1.0
            self.fd = _Filter(w, cfg.sample_period_s, d)
            self.terms = [_Filter(w, cfg.sample_period_s, 0.0) for _ in range(5)]
            for f, x in zip(self.terms, self._raw_terms(d, s, lam, voltage_V)):
                f.x = x
        if self._buffer.shape[1]:
            j = self._count % self._buffer.shape[1]
            self._buffer[0, j], self._buffer[1, j], self._buffer[2, j] = d, voltage_V, float(bool(saturated))
            self._count += 1
        self._creep_step(lam - 1.0, cfg.sample_period_s)
        self.fd.step(d)
        for f, x in zip(self.terms, self._raw_terms(d, s, lam, voltage_V)):
            f.step(x)
        self.k += 1
        if self.k % self.every:
            return
        if not self.enabled or saturated or abs(self.fd.a) > cfg.max_filtered_acceleration_m_per_s2:
            self.skipped += 1
            return
        self._kalman_update()

    def _raw_terms(self, d, s, lam, voltage_V):
        """Per sample: the static weight term and the four regressors, Pa (filtered afterwards)."""
        m = self.model
        return (m.g * s / (m.force_gain * d), m.c2 * s * voltage_V * voltage_V, m.hyperelastic_stress(s),
                m.k1 * (lam - 1.0 - self.eps1), -m.k1 * self.psi)

    def _creep_step(self, f: float, dt: float) -> None:
        """eps1 along the measured d with the tracked tau, and psi = d eps1 / d ln tau (exact exponential)."""
        tau = self.tau0_s * math.exp(self.x[3])
        a = math.exp(-dt / tau)
        self.psi = self.psi * a + (self.eps1 - f) * a * dt / tau
        self.eps1 = f + (self.eps1 - f) * a

    def _move_creep_time(self, delta: float) -> None:
        """Carry a change of ln tau into the creep state and its filtered term (first order along psi).

        eps1 and the filtered k1 term are histories computed with the tracked tau: without this
        correction a new tau acts only on the future and the estimate of tau lags its own update
        (the creep state is part of the estimated model, as in an augmented-state EKF).
        """
        if delta == 0.0 or not self.terms:
            return
        self.eps1 += self.psi * delta
        k_term, psi_term = self.terms[3], self.terms[4]
        k_term.x += psi_term.x * delta
        k_term.v += psi_term.v * delta

    def _regression(self):
        """(y, H, h(x)) of the normalised force balance: the filtered terms, inertia and damping at the filtered d."""
        m = self.model
        d, v, acc = self.fd.x, self.fd.v, self.fd.a
        s = 1.0 + d * d / m.l0_sq
        phi = d / (m.l0_sq * math.sqrt(s))
        w, g_term, h_term, k_term, psi_term = (f.x for f in self.terms)
        y = w - acc * s / (m.force_gain * d) - m.eta2 * phi * v
        th_g, th_h, th_1, _ = self.x
        H = np.array([g_term, h_term, k_term, th_1 * psi_term]) / self.scale
        pred = (th_g * g_term + th_h * h_term + th_1 * k_term) / self.scale
        return y / self.scale, H, pred

    def _kalman_update(self) -> None:
        cfg = self.config
        y, H, pred = self._regression()
        self.P = self.P + self.Q
        r = cfg.residual_std ** 2
        PH = self.P @ H
        S = float(H @ PH) + r
        K = PH / S
        innov = y - pred
        dx = np.clip(K * innov, -cfg.max_step, cfg.max_step)
        x_new = np.clip(self.x + dx, self.lo, self.hi)
        self._move_creep_time(float(x_new[3] - self.x[3]))
        self.x = x_new
        self.P = self.P - np.outer(K, PH)
        self.P = 0.5 * (self.P + self.P.T)
        diag = np.minimum(np.diag(self.P), self.P_max)          # the cap of the covariance
        scale = np.sqrt(np.maximum(diag, 1e-30) / np.maximum(np.diag(self.P), 1e-30))
        self.P = self.P * np.outer(scale, scale)
        self.updates += 1
        a = min(cfg.update_period_s, 1.0)
        if self._last_h is not None:
            self._excitation = (1 - a) * self._excitation + a * float(np.sum((H - self._last_h) ** 2))
        self._last_h = H
        self._residual = (1 - a) * self._residual + a * innov * innov

    # ------------------------------------------------------- windowed least squares
    def window(self):
        """A copy of the buffered samples, oldest first: (d m, applied voltage V, saturated) or None."""
        n = self._buffer.shape[1]
        if not n or self._count < n // 4 or not self.enabled:
            return None
        if self._count < n:
            return self._buffer[:, :self._count].copy()
        j = self._count % n
        return np.concatenate((self._buffer[:, j:], self._buffer[:, :j]), axis=1)

    def fit(self, window) -> WindowFit | None:
        """The windowed least squares on a :meth:`window` (slow, ~0.1 s: run it off the control loop)."""
        cfg = self.config
        if window is None or cfg.window is None:
            return None
        return fit_window(self.model, self.scale, self.tau0_s, window[0], window[1], window[2] > 0.5,
                          cfg.sample_period_s, cfg.filter_Hz, cfg.bounds,
                          cfg.max_filtered_acceleration_m_per_s2, cfg.window)

    def absorbed(self, fit: WindowFit | None, x=None) -> np.ndarray:
        """The estimate (``x``, default the current one) after :meth:`absorb` (informative ratios only,
        bounded jump, physical bounds)."""
        x = np.array(self.x if x is None else x, dtype=float)
        if fit is None:
            return x
        for i, (xi, ok, jump) in enumerate(zip(fit.x, fit.informative, self.config.window.max_jump)):
            if ok:
                x[i] = min(max(x[i] + min(max(xi - x[i], -jump), jump), self.lo[i]), self.hi[i])
        return x

    def absorbed_delay(self, fit: WindowFit | None, extra_delay_s: float | None = None) -> float:
        """The extra loop delay (``extra_delay_s``, default the current one) after :meth:`absorb` (moved
        only by an informative fit, inside the grid), s."""
        if fit is None or not fit.delay_informative:
            return self.extra_delay_s if extra_delay_s is None else float(extra_delay_s)
        lo, hi, _ = self.config.window.delay_grid_s
        return min(max(fit.extra_delay_s, lo), hi)

    def absorb(self, fit: WindowFit | None) -> None:
        """Move the estimate to the window's fit where it is informative; its error becomes the covariance."""
        if fit is None:
            return
        self.extra_delay_s = self.absorbed_delay(fit)
        if not any(fit.informative):
            return
        x = self.absorbed(fit)
        if fit.informative[3]:
            self._move_creep_time(float(x[3] - self.x[3]))
            self.eps1 = fit.eps1_end
        for i, ok in enumerate(fit.informative):
            if ok:
                self.P[i, :] = 0.0
                self.P[:, i] = 0.0
                self.P[i, i] = max(fit.std[i] ** 2, 1e-10)
        self.x = x
        self.fits += 1

    # ---------------------------------------------------------------- results
    @property
    def ratios(self) -> dict:
        """Tracked / identified: electrostatic gain, static stiffness, viscoelastic stiffness, creep time."""
        return dict(zip(NAMES, (float(self.x[0]), float(self.x[1]), float(self.x[2]), float(math.exp(self.x[3])))))

    def result(self) -> TrackedModel:
        sd = np.sqrt(np.diag(self.P))
        std = dict(zip(NAMES, (float(sd[0]), float(sd[1]), float(sd[2]), float(math.exp(self.x[3]) * sd[3]))))
        return TrackedModel(self.ratios, std, self.updates, self.skipped, math.sqrt(self._excitation),
                            math.sqrt(self._residual))

    def tracked_parameters(self, x=None) -> MembraneParameters:
        """The identified membrane with the tracked drift (or the estimate ``x``) applied (eps_r, sigma_h, k1, eta1)."""
        p = self.params
        if x is None:
            x = self.x
        r = dict(zip(NAMES, (float(x[0]), float(x[1]), float(x[2]), float(math.exp(x[3])))))
        k1 = p.k1_Pa * r["viscoelastic_stiffness"]
        return p.replace(name=f"{p.name} (tracked)",
                         relative_permittivity=p.relative_permittivity * r["electrostatic_gain"],
                         beta_Pa=tuple(b * r["static_stiffness"] for b in p.beta_Pa),
                         gamma_Pa=tuple(g * r["static_stiffness"] for g in p.gamma_Pa),
                         k1_Pa=k1, eta1_Pa_s=k1 * self.tau0_s * r["creep_time"])
