"""The controller on the tracked model: the feedforward and the gain design follow the membrane's drift.

:class:`AdaptiveModel` feeds :class:`~.tracking.ModelTracker` with every sample the controller sees
(measured d, commanded voltage, saturation) and, every ``retune_period_s``, when a tracked ratio
moved by more than ``retune_threshold`` since the model in use, retunes the controller in two
steps, so that the slow part can run off the control loop (a node: in a worker process,
:mod:`.retune_worker`):

* :func:`prepare_plan` of a :class:`RetuneRequest` (slow: ~0.1-0.3 s each; :meth:`AdaptiveModel.prepare`
  in this process): the windowed least squares of the last samples (:mod:`.window_fit`: the
  tracker's EKF alone converges slowly on k1 and the creep time), then :func:`prepare_retune`: the
  inverse (eqs. 5, 20 with the tracked parameters) and the feedback gains (pole placement on it, as
  at start-up). The request holds plain data only (the window's arrays, the tracker's estimate, the
  parameters and settings: a few hundred kB pickled), the plan is ~2 kB: both cross a process
  boundary cheaply, the controller never does;
* :func:`apply_retune` (fast): swaps them into the controller, bumpless -- the integrator absorbs
  the change of the feedforward at the current reference, so the command does not jump -- and
  keeps the reference, the strain integrator's state and the PID's state.

``enabled = False`` stops both the tracking updates and the retuning (the identified model stays).

:class:`DriftTracking` is the same without a controller (model_node's membrane health: applied voltage
and measured d): the same tracker, the same window fit every ``retune_period_s`` through
:func:`prepare_plan` (a request without controller settings: the plan carries the fit only) and the
same absorption; :class:`AdaptiveModel` is a :class:`DriftTracking` that also retunes its controller.
Both run off the loop through :class:`.retune_worker.BackgroundRetune`, so the two nodes' health reads
the same estimate on the same data.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from ..model import MembraneParameters
from .controller import ControlOutput, ControllerConfig, PositionController
from .feedback import FeedbackGains, design_gains
from .inverse import ModelInverse
from .tracking import ModelTracker, TrackerConfig
from .window_fit import WindowFit

__all__ = ["RetunePlan", "RetuneRequest", "prepare_plan", "prepare_retune", "apply_retune", "DriftTracking",
           "AdaptiveModel"]


@dataclass(frozen=True)
class RetunePlan:
    """The controller's model parts for one set of parameters (built by :func:`prepare_retune`)."""

    params: MembraneParameters
    inverse: ModelInverse | None     # None: nothing to retune (the fit is absorbed all the same)
    gains: FeedbackGains | None
    ratios: dict
    fit: WindowFit | None = None
    config: ControllerConfig | None = None   # the controller's settings with the tracked loop delay


@dataclass(frozen=True)
class RetuneRequest:
    """All that :func:`prepare_plan` needs, as plain data (picklable; no controller, no tracker)."""

    identified: MembraneParameters
    tracker_config: TrackerConfig
    x: tuple                       # the tracker's estimate: theta_g, theta_h, theta_1, ln(tau/tau0)
    extra_delay_s: float           # the tracker's extra loop delay, s
    in_use: dict                   # the ratios of the model in use (1 = identified)
    config: ControllerConfig | None       # the controller's settings now (None: no controller, only the fit)
    configured: ControllerConfig | None   # its settings at start-up (the configured loop delay)
    retune_threshold: float
    delay_deadband_s: float
    window: np.ndarray | None      # (3, n): d m, applied voltage V, saturated; None: no window fit


#: the robustness bound is relaxed by this factor when a measured loop delay admits no design at the configured one
SENSITIVITY_RELAXATION = 1.3


def prepare_retune(ctl: PositionController, params: MembraneParameters, ratios: dict | None = None,
                   config: ControllerConfig | None = None) -> RetunePlan:
    """The inverse and the gains for ``params`` with ``config`` (default ctl's) (slow; touches nothing of ctl).

    An explicit ``config`` (the measured loop delay) for which no gains meet ``max_sensitivity``
    is designed once more with the bound relaxed by :data:`SENSITIVITY_RELAXATION`.
    """
    return design_retune(params, config or ctl.config, ratios, relax=config is not None)


def design_retune(params: MembraneParameters, cfg: ControllerConfig, ratios: dict | None = None,
                  relax: bool = True) -> RetunePlan:
    """:func:`prepare_retune` on plain settings: with ``relax``, a ``cfg`` admitting no gains is designed
    once more with the robustness bound x :data:`SENSITIVITY_RELAXATION` (ValueError when even that fails)."""
    inverse = ModelInverse(params, cfg.max_voltage_V)
    lo, hi = inverse.reachable_range_m
    d_op = 0.5 * (lo + hi) if cfg.operating_point_m is None else float(cfg.operating_point_m)
    try:
        gains = design_gains(inverse, d_op, cfg.design_delay_s, cfg.sample_period_s, cfg.max_sensitivity,
                             cfg.max_noise_gain)
    except ValueError:
        if not relax:
            raise
        gains = design_gains(inverse, d_op, cfg.design_delay_s, cfg.sample_period_s,
                             cfg.max_sensitivity * SENSITIVITY_RELAXATION, cfg.max_noise_gain)
    return RetunePlan(params, inverse, gains, dict(ratios or {}), config=cfg if relax else None)


@functools.lru_cache(maxsize=4)
def _tracker_for(params: MembraneParameters, config: TrackerConfig) -> ModelTracker:
    """A tracker of the identified membrane, used only for its pure methods (fit, absorbed, parameters)."""
    return ModelTracker(params, config)


def prepare_plan(request: RetuneRequest, tracker: ModelTracker | None = None) -> RetunePlan:
    """Slow (run it off the control loop): the window's fit, and the retune when a ratio moved enough.

    ``tracker``: one of the request's identified membrane and tracker settings (default: a cached one);
    only its pure methods are used, its state is the request's.
    """
    r = request
    tracker = tracker or _tracker_for(r.identified, r.tracker_config)
    window = r.window
    fit = tracker.fit(window) if window is not None and len(window) else None
    x = tracker.absorbed(fit, r.x)
    params = tracker.tracked_parameters(x)
    ratios = {k: v for k, v in zip(r.in_use, (float(x[0]), float(x[1]), float(x[2]), math.exp(x[3])))}
    if r.config is None:        # no controller (model_node): the fit only, absorbed by the caller
        return RetunePlan(params, None, None, ratios, fit)
    extra = tracker.absorbed_delay(fit, r.extra_delay_s)
    config = r.configured if abs(extra) < r.delay_deadband_s else dataclasses.replace(
        r.configured, loop_delay_s=max(r.configured.loop_delay_s + extra, 0.0))
    if (max(abs(ratios[k] / r.in_use[k] - 1.0) for k in ratios) < r.retune_threshold
            and config.loop_delay_s == r.config.loop_delay_s):
        return RetunePlan(params, None, None, ratios, fit)
    try:
        plan = design_retune(params, config, ratios)
    except ValueError:          # no design even relaxed for the measured delay: the configured one
        plan = design_retune(params, r.configured, ratios)
    return dataclasses.replace(plan, fit=fit)


def apply_retune(ctl: PositionController, plan: RetunePlan, t_s: float | None = None) -> None:
    """Swap ``plan`` into ``ctl`` without a jump of the command (at the reference of time ``t_s``)."""
    old_inverse = ctl.inverse
    started = ctl.started and t_s is not None and ctl.strain is not None
    if started:
        d, v, a = ctl.reference_at(t_s)
        eps1 = ctl.strain.eps1
        pid = ctl.pid
        e = pid.last_error or 0.0
        g_old = pid.gains
        a_fb_old = g_old.kp_per_s2 * e + g_old.ki_per_s3 * pid.integral + g_old.kd_per_s * pid.derivative
        u2_fb_old = a_fb_old / float(old_inverse.input_gain(d))
        delta_ff = plan.inverse.dynamic_u2(d, v, a, eps1) - old_inverse.dynamic_u2(d, v, a, eps1)
    ctl.params = plan.params
    ctl.inverse = plan.inverse
    if plan.config is not None:
        ctl.config = plan.config               # the feedforward lead follows the loop delay
    ctl.max_voltage_V = min(ctl.config.max_voltage_V, plan.inverse.top_voltage_V)
    ctl.usable_range_m = ctl.usable_range()    # the ends of the range follow the tracked model (a payload moves them)
    ctl.gains = plan.gains
    ctl.pid.gains = plan.gains
    if ctl.strain is not None:
        ctl.strain.inverse = plan.inverse
        ctl.strain.rate = plan.inverse.model.relax_rate
    if started and math.isfinite(delta_ff) and plan.gains.ki_per_s3 > 0.0:
        g = plan.gains
        a_fb_new = (u2_fb_old - delta_ff) * float(plan.inverse.input_gain(d))
        rest = g.kp_per_s2 * e + g.kd_per_s * pid.derivative
        pid.integral = (a_fb_new - rest) / g.ki_per_s3


class DriftTracking:
    """Online tracking with the periodic window fit, without a controller (model_node; the base of
    :class:`AdaptiveModel`): the same tracker, the same :func:`prepare_plan` and the same absorption.

    Per sample: :meth:`observe` (measured d m, applied voltage V). Every ``retune_period_s`` of samples
    :meth:`due` hands out the window; :meth:`prepare` (here, or a worker: :class:`.retune_worker.BackgroundRetune`)
    fits it (a request without controller settings: a plan that only carries the fit) and :meth:`apply`
    absorbs the fit into the tracker (:meth:`.tracking.ModelTracker.absorb`). ``enabled = False``: no
    tracking, no fit.
    """

    def __init__(self, params: MembraneParameters, config: TrackerConfig | None = None,
                 retune_period_s: float = 2.0, enabled: bool = True):
        self.identified = params
        self.configured: ControllerConfig | None = None
        self.retune_threshold = 0.0
        self.delay_deadband_s = 0.0
        self.tracker = ModelTracker(params, config)
        self.retune_period_s = float(retune_period_s)
        self.enabled = bool(enabled)
        self.tracker.enabled = self.enabled
        self.in_use = {name: 1.0 for name in self.tracker.ratios}
        self.last_retune_s: float | None = None
        self.retunes = 0
        self.fits_absorbed = 0           # plans whose window fit was absorbed (informative or not)

    @property
    def controller_config(self) -> ControllerConfig | None:
        """The controller's settings now (None: no controller, the plan only fits)."""
        return None

    def observe(self, t_s: float, measured_m: float, voltage_V: float, saturated: bool = False) -> None:
        """One sample: the measured displacement (m) and the voltage applied meanwhile (V)."""
        if self.enabled:
            self.tracker.update(measured_m, voltage_V, saturated)
        if self.last_retune_s is None:
            self.last_retune_s = t_s

    def resting(self, t_s: float) -> bool:
        """Whether a fit may be prepared at t_s (the controller: not while its reference moves)."""
        return True

    def due(self, t_s: float):
        """The window of samples (:meth:`ModelTracker.window`, or an empty tuple without one) when a fit
        is due at t_s, else None (cheap: a copy of the buffer)."""
        if not self.enabled or self.last_retune_s is None or t_s - self.last_retune_s < self.retune_period_s:
            return None
        if not self.resting(t_s):
            return None            # the next sample at rest
        self.last_retune_s = t_s
        window = self.tracker.window()
        return () if window is None else window

    def request(self, window) -> RetuneRequest:
        """The plain data of a retune on ``window`` (cheap: the estimate now, the settings, the window)."""
        tr = self.tracker
        return RetuneRequest(self.identified, tr.config, tuple(float(v) for v in tr.x), float(tr.extra_delay_s),
                             dict(self.in_use), self.controller_config, self.configured, self.retune_threshold,
                             self.delay_deadband_s, window if window is not None and len(window) else None)

    def prepare(self, window) -> RetunePlan:
        """Slow (run it off the control loop): :func:`prepare_plan` of :meth:`request` in this process."""
        return prepare_plan(self.request(window), self.tracker)

    def apply(self, plan: RetunePlan | None, t_s: float) -> None:
        """Absorb the plan's window fit into the tracker."""
        if plan is None:
            return
        self.tracker.absorb(plan.fit)
        self.fits_absorbed += 1

    def step(self, t_s: float, measured_m: float, out) -> bool:
        """observe + (synchronously) prepare and apply a due plan: for simulations; True when the controller
        was retuned (never without one). ``out``: what :meth:`observe` takes after the displacement (here the
        applied voltage, V; AdaptiveModel: the ControlOutput)."""
        self.observe(t_s, measured_m, out)
        window = self.due(t_s)
        if window is None:
            return False
        before = self.retunes
        self.apply(self.prepare(window), t_s)
        return self.retunes > before


class AdaptiveModel(DriftTracking):
    """Online tracking + retuning of one :class:`PositionController` (no ROS, no threads).

    Per sample: :meth:`observe` (after ``ctl.update``). :meth:`due` says when a retune should be
    prepared (returns the window of samples to fit); the caller runs :meth:`prepare` (here or in a
    worker) and hands the plan to :meth:`apply`.
    """

    def __init__(self, ctl: PositionController, config: TrackerConfig | None = None,
                 retune_period_s: float = 2.0, retune_threshold: float = 0.005, enabled: bool = True,
                 delay_deadband_s: float = 0.3e-3):
        super().__init__(ctl.params, config, retune_period_s, enabled)
        self.ctl = ctl
        self.configured = ctl.config
        self.delay_deadband_s = float(delay_deadband_s)
        self.retune_threshold = float(retune_threshold)

    @property
    def controller_config(self) -> ControllerConfig:
        return self.ctl.config

    def observe(self, t_s: float, measured_m: float, out: ControlOutput) -> None:
        """One sample: the measured displacement and the controller's output for it."""
        super().observe(t_s, measured_m, out.voltage_V, out.saturated != 0)

    def resting(self, t_s: float) -> bool:
        state = self.ctl.state
        return state is None or t_s > state.trajectory.end_s

    def apply(self, plan: RetunePlan | None, t_s: float) -> None:
        super().apply(plan, t_s)
        if plan is None or plan.inverse is None:
            return
        apply_retune(self.ctl, plan, t_s)
        self.in_use = dict(plan.ratios)
        self.retunes += 1
