"""Experiments that ask the right questions (issue 21, item 3): a Fisher-information experiment planner.

From a first fit -- its Fisher information F = J^T J (the weighted Jacobian of the joint refinement,
:meth:`~dea_ros.identify.result.IdentificationResult.fisher_information`, written to params.yaml) and
its parameters -- every candidate experiment within the amplifier limits (a sine record: frequency,
amplitude, offset; a step from 0 V: its level; a static point: its voltage, at another mass only
where the rig has one) gets the information it would add, G_c = J_c^T J_c, with J_c the weighted
Jacobian of that record's residuals at the fitted parameters. J_c comes from the joint refinement's
own objective (:class:`~dea_ros.identify.joint_fit.JointObjective`: harmonic-balance sensitivities of
d_rms, the collocation sensitivities of a step, implicit differentiation of eq. 20), with the
weights the refit will give the record: the laser noise sigma on every step sample, sigma *
sqrt(1/N + 1/N0) on an RMS value measured over N samples (N0 baseline samples of the rest position;
the bound of :func:`~dea_ros.identify.experiments.records.rms_statistics` for white noise), the first
fit's static residual scatter on a static point.

The expected 95 % half-widths are t * sqrt(s^2 [F^-1]_ii) in relative units (ln for k1, eta1, eta2,
value-relative for eps_r and the stress combinations), s^2 the first fit's chi^2/dof; a direction no
record sees has an infinite width (counted as ``WIDTH_CAP`` by the criterion). Greedy selection:
repeatedly add the candidate with the largest decrease of the criterion per second of experiment
time that still fits the budget, until the budget is spent or no candidate helps. Criteria over the
target parameters (default: eps_r, k1, eta1, eta2, sigma_h''(1)):

* ``widths`` (default): sum of ln(width) -- every target's relative shrinkage counts the same, so the
  eta1/eta2 trade-off is broken as eagerly as the curvature is pinned;
* ``A``: sum of width^2 -- the widest intervals dominate.

A correlation goal comes first (``max_correlation``, default 0.9, for the pairs of
``CORRELATION_GOAL_PAIRS``: eta1/eta2, the viscous trade-off of a fast creep): while the expected
|correlation| of such a pair is above it, the pick is the record that lowers it most per second; once it
is at or below, the criterion picks among the records that keep it there. Neither criterion aims at a
correlation: on the fast-creep membranes of the coverage family (F08, F11: creep 0.07-0.17 s) they left
it at 0.92-0.96 where a low-frequency offset sine or a step brings it under 0.9 at the same time and
nearly the same widths (session 21). ``max_correlation=None`` (or 1) switches the goal off.

The result (:class:`ExperimentPlan`) holds the picks with the expected widths after each, and the
widths and the eta1/eta2 correlation before and after; :func:`plan_protocol` turns the picks into
protocol segments the identifier node runs (:mod:`~dea_ros.identify.protocols`).

Every record is held before it is measured until its transient is below ``PlanLimits.settle_tolerance_m``
(:func:`record_settle`): the slowest time constant of the model linearised at the record's operating
point (:func:`~dea_ros.model.settling.settle_time`; on a slow membrane several creep times eta1/k1)
x ln(transient / tolerance), at least the fixed holds of :class:`PlanLimits`, at most ``max_settle_s``
(then the plan's notes say the record is measured unsettled). A record's cost includes its hold. Where the
cap bites, the transient left when the record is measured (``CandidateRecord.transient_left_m``) is an error
the noise does not state: it is added to the record's uncertainty (in quadrature), as the bag extraction adds
a record's unsettled change, and a record where the membrane is not stable is no candidate (session 20:
records at the resonance peak held 96 s with 0.2-0.4 um left were picked for their information and biased
the second pass's k1 by six standard errors).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DeaRosError, PlanningError
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..model.settling import SettleTime, settle_time
from ..model.yaml_files import read_yaml_mapping
from ..solvers.inputs import SinePeriodic
from ..solvers.sweep import frequency_sweep, orbit_time_constants
from .determination import SINGULAR_EIGENVALUE_RATIO, inverse_diagonal
from .experiments import StaticData, StepData
from .frequency_points import FrequencyPoint
from .joint_fit import JointObjective, curvature_mode
from .protocols import Protocol

__all__ = ["FirstFit", "PlanLimits", "CandidateRecord", "PlannedRecord", "ExperimentPlan", "first_fit_from_file",
           "first_fit_from_result", "fit_widths", "candidate_records", "candidate_information", "plan_experiments",
           "plan_protocol", "step_rest_s", "record_settle", "sine_record_cost", "PlanningError", "MIN_DECREASE",
           "DEFAULT_TARGETS", "WIDTH_CAP", "T95", "CORRELATION_GOAL_PAIRS", "DEFAULT_MAX_CORRELATION"]

DEFAULT_TARGETS = ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s", "sigma_h''(1)_Pa")
#: relative 95 % half-width a direction no record sees counts as (100 x the value)
WIDTH_CAP = 100.0
T95 = 1.96
#: a record must lower the criterion by at least this much to be picked (widths: 0.1 % of one width;
#: A: this fraction of the criterion before the plan)
MIN_DECREASE = 1e-3
_LOG_NAMES = ("k1_Pa", "eta1_Pa_s", "eta2_Pa_s")
#: pairs the correlation goal of :func:`plan_experiments` applies to (both must be fitted)
CORRELATION_GOAL_PAIRS = (("eta1_Pa_s", "eta2_Pa_s"),)
DEFAULT_MAX_CORRELATION = 0.9


@dataclass(frozen=True)
class FirstFit:
    """What the planner needs of the first fit: parameters and Fisher information (statistics' units)."""

    parameters: MembraneParameters
    names: tuple
    values: np.ndarray
    information: np.ndarray        # F = J^T J of the weighted residuals, statistics' units
    variance_factor: float         # s^2 = chi^2 / dof: covariance = s^2 F^-1
    laser_noise_m: float
    static_sigma_m: float
    reported_ci95: dict = field(default_factory=dict)   # name -> [low, high] as params.yaml states it
    source: str = ""
    #: the first fit's own doubts (a parameter at its search bound, no convergence): the plan is
    #: linearised at that fit and may not help if it is in the wrong basin
    warnings: tuple = ()

    def scale(self) -> np.ndarray:
        """Per parameter: multiply a statistics-unit column by it to get relative units."""
        return np.array([1.0 if n in _LOG_NAMES else max(abs(float(v)), 1e-30)
                         for n, v in zip(self.names, self.values)])


def first_fit_from_result(result) -> FirstFit:
    """The :class:`FirstFit` of an :class:`~dea_ros.identify.result.IdentificationResult`."""
    info = result.fisher_information()
    if info is None:
        raise PlanningError("the identification has no joint refinement: no Fisher information to plan from")
    return _first_fit(result.parameters, info, {}, "identification result")


def first_fit_from_file(path) -> FirstFit:
    """The :class:`FirstFit` of a params.yaml written by ``dea-ros identify``."""
    path = Path(path)
    data = read_yaml_mapping(path, PlanningError, "file", fix="give the params.yaml written by dea-ros identify",
                             mapping="a mapping (membrane, identification, ...)")
    ident = data.get("identification")
    info = ident.get("fisher_information") if isinstance(ident, dict) else None
    if not isinstance(info, dict):
        raise PlanningError(f"{path}: no 'identification: fisher_information' section; plan from the params.yaml "
                            "of a dea-ros identify run with the joint refinement (re-run identify if it is older)")
    try:
        params = MembraneParameters.from_yaml(path)
    except DeaRosError as exc:
        raise PlanningError(f"{path}: {exc}") from None
    reported = {n: v.get("ci95") for n, v in (ident.get("parameters") or {}).items() if isinstance(v, dict)}
    return _first_fit(params, info, reported, str(path))


def _first_fit(params: MembraneParameters, info: dict, reported: dict, source: str) -> FirstFit:
    try:
        names = tuple(str(n) for n in info["names"])
        values = np.asarray(info["values"], float)
        matrix = np.asarray(info["matrix"], float)
        var = float(info["variance_factor"])
        noise = info.get("laser_noise_m")
        static_sigma = float(info.get("static_sigma_m") or float("nan"))
    except (KeyError, TypeError, ValueError) as exc:
        raise PlanningError(f"{source}: fisher_information is incomplete or malformed ({exc})") from None
    p = len(names)
    if values.shape != (p,) or matrix.shape != (p, p) or not np.all(np.isfinite(matrix)) or not var > 0:
        raise PlanningError(f"{source}: fisher_information: {p} names need {p} values and a finite {p}x{p} matrix "
                            "and a positive variance_factor")
    if noise is None or not float(noise) > 0:
        raise PlanningError(f"{source}: fisher_information has no laser_noise_m (the first fit had no step)")
    warnings = tuple(str(w) for w in (info.get("first_fit_warnings") or ()))
    return FirstFit(params, names, values, matrix, var, float(noise), static_sigma, reported, source, warnings)


@dataclass(frozen=True)
class PlanLimits:
    """The candidate grid and the rig's limits (V, V/s, Hz, s, kg)."""

    max_voltage_V: float = 2500.0
    slew_rate_V_per_s: float = 100000.0
    min_frequency_Hz: float = 0.3
    max_frequency_Hz: float = 40.0
    n_frequencies: int = 24
    amplitude_fractions: tuple = (0.6, 0.8, 1.0)    # of max_voltage_V (sines without offset)
    offsets: bool = True                             # also u = U/2 + U/2 sin (offset = amplitude, peak U)
    step_fractions: tuple = (0.6, 0.8, 1.0)          # step levels from 0 V
    static_fractions: tuple = (0.5, 0.7, 0.9, 1.0)   # static points at the dynamic mass
    other_masses_kg: tuple = ()                      # masses the rig has besides the dynamic one
    settle_s: float = 8.0                            # sine: transient discarded, at least (whole periods)
    measure_s: float = 3.0                           # sine: measured (whole periods)
    step_pre_s: float = 0.5
    step_hold_s: float = 5.0
    step_rest_min_s: float = 2.0                     # rest at 0 V before a step, at least (step_rest_s)
    static_hold_s: float = 4.0                       # static hold, at least (its last static_measure_s measured)
    static_measure_s: float = 1.0
    sample_rate_Hz: float = 1000.0
    #: what may be left of a transient when a record is measured (record_settle): 3 nm, a tenth of the
    #: standard error of a static point's mean (1 um laser noise, the ILD1320's, over 1 s at 1 kHz: 32 nm)
    settle_tolerance_m: float = 3e-9
    #: no hold longer than this; where the cap bites the plan says so (its notes)
    max_settle_s: float = 60.0

    def __post_init__(self):
        for name in ("max_voltage_V", "slew_rate_V_per_s", "min_frequency_Hz", "max_frequency_Hz", "settle_s",
                     "measure_s", "step_pre_s", "step_hold_s", "step_rest_min_s", "static_hold_s", "static_measure_s",
                     "sample_rate_Hz", "settle_tolerance_m", "max_settle_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise PlanningError(f"plan limits: {name} must be a positive number, got {v!r}")
        if self.min_frequency_Hz >= self.max_frequency_Hz:
            raise PlanningError("plan limits: min_frequency_Hz must be below max_frequency_Hz")
        for name in ("amplitude_fractions", "step_fractions", "static_fractions"):
            if any(not (0 < float(f) <= 1) for f in getattr(self, name)):
                raise PlanningError(f"plan limits: {name} must lie in (0, 1] (fractions of max_voltage_V)")
        if any(not (isinstance(m, (int, float)) and math.isfinite(m) and m > 0) for m in self.other_masses_kg):
            raise PlanningError(f"plan limits: other_masses_kg must be positive masses in kg (a hold's settle time "
                                f"needs the mass's dynamics), got {tuple(self.other_masses_kg)!r}")


@dataclass(frozen=True)
class CandidateRecord:
    """One experiment the rig can run (V, Hz, kg, s)."""

    kind: str                       # "sine", "step", "static"
    duration_s: float               # experiment time it costs
    mass_kg: float
    frequency_Hz: float = float("nan")
    amplitude_V: float = float("nan")
    offset_V: float = 0.0
    final_V: float = float("nan")   # step from 0 V
    voltage_V: float = float("nan")  # static point
    measured_samples: int = 0        # samples the sine's RMS or the static mean is measured over
    #: held before the record is measured (the rest before a step, a static point's hold, a sine's settle),
    #: from the slowest time constant at its operating point (record_settle), and that time constant
    settle_s: float = float("nan")
    time_constant_s: float = float("nan")
    settle_warning: str = ""         # the cap bit (or no equilibrium): the record is measured unsettled
    #: where the cap bit: the transient left when it is measured (m; inf where the membrane is not stable
    #: there), an uncertainty of the record beyond the noise; 0 where it settles
    transient_left_m: float = 0.0

    def label(self) -> str:
        if self.kind == "sine":
            off = f" + {self.offset_V:.0f} V offset" if self.offset_V else ""
            return f"sine {self.frequency_Hz:.3g} Hz, {self.amplitude_V:.0f} V{off}"
        if self.kind == "step":
            return f"step 0 -> {self.final_V:.0f} V"
        return f"static {self.voltage_V:.0f} V at {self.mass_kg * 1e3:.3g} g"

    def to_dict(self) -> dict:
        out = {"kind": self.kind, "label": self.label(), "duration_s": self.duration_s, "mass_kg": self.mass_kg,
               "settle_s": self.settle_s, "time_constant_s": self.time_constant_s}
        if self.transient_left_m:
            out["transient_left_m"] = self.transient_left_m
        if self.kind == "sine":
            out.update(frequency_Hz=self.frequency_Hz, amplitude_V=self.amplitude_V, offset_V=self.offset_V)
        elif self.kind == "step":
            out.update(initial_V=0.0, final_V=self.final_V)
        else:
            out.update(voltage_V=self.voltage_V)
        return out


@dataclass
class PlannedRecord:
    """A picked record: its expected effect (relative 95 % half-widths after it and the earlier picks)."""

    record: CandidateRecord
    criterion_decrease: float
    decrease_per_s: float
    widths_after: dict

    def to_dict(self) -> dict:
        return {**self.record.to_dict(), "criterion_decrease": self.criterion_decrease,
                "decrease_per_s": self.decrease_per_s, "relative_ci95_after": dict(self.widths_after)}


@dataclass
class ExperimentPlan:
    """The planner's result (module docstring): widths are relative 95 % half-widths (0.01 = 1 %)."""

    names: tuple
    targets: tuple
    criterion: str
    budget_s: float
    widths_before: dict
    widths_after: dict
    correlation_before: dict        # "eta1/eta2" etc.: correlation of the pair, before and after
    correlation_after: dict
    picks: list
    n_candidates: int
    source: str = ""
    notes: list = field(default_factory=list)
    max_correlation: float | None = None   # the correlation goal the plan was made with (None: none)

    @property
    def total_s(self) -> float:
        return float(sum(p.record.duration_s for p in self.picks))

    def to_dict(self) -> dict:
        return {"source": self.source, "criterion": self.criterion, "max_correlation": self.max_correlation,
                "budget_s": self.budget_s,
                "total_s": self.total_s, "targets": list(self.targets), "candidates": self.n_candidates,
                "relative_ci95_before": dict(self.widths_before), "relative_ci95_after": dict(self.widths_after),
                "correlation_before": dict(self.correlation_before),
                "correlation_after": dict(self.correlation_after),
                "picks": [p.to_dict() for p in self.picks], "notes": list(self.notes)}


def sine_record_cost(limits: PlanLimits, f: float, settle_s: float | None = None) -> tuple:
    """(experiment time, measured samples) of one sine record, whole periods as the protocol runs it;
    ``settle_s`` (default ``limits.settle_s``): the transient discarded before it."""
    periods = max(1, math.ceil(limits.measure_s * f - 1e-9))
    settle = math.ceil((limits.settle_s if settle_s is None else settle_s) * f - 1e-9) / f
    return settle + periods / f, int(round(periods / f * limits.sample_rate_Hz))


def _frequency_grid(params: MembraneParameters, limits: PlanLimits) -> np.ndarray:
    """Geometric over the band plus 11 across 0.85-1.15 of the model's resonance (where it has one)."""
    grid = list(np.geomspace(limits.min_frequency_Hz, limits.max_frequency_Hz, limits.n_frequencies))
    try:
        sweep = frequency_sweep(params, SinePeriodic(limits.max_voltage_V, 1.0),
                                np.geomspace(max(limits.min_frequency_Hz, 1.0), limits.max_frequency_Hz, 30),
                                n_harmonics=8, branch_switching=False, realised=False)
        f_r = float(sweep.resonance_peak()["frequency_Hz"])
    except (DeaRosError, ArithmeticError, ValueError, KeyError):
        f_r = float("nan")
    if math.isfinite(f_r):
        grid += list(np.linspace(0.85, 1.15, 11) * f_r)
    grid = [f for f in grid if limits.min_frequency_Hz <= f <= limits.max_frequency_Hz]
    return np.array(sorted({round(float(f), 3) for f in grid}))


def record_settle(params: MembraneParameters, limits: PlanLimits, kind: str, voltage_V: float = 0.0,
                  amplitude_V: float = 0.0, offset_V: float = 0.0, mass_kg: float | None = None,
                  orbit_time_constant_s: float = 0.0) -> SettleTime:
    """How long a record is held before it is measured (:func:`~dea_ros.model.settling.settle_time`: the
    slowest time constant of the linearised model at the record's operating point x ln(transient /
    ``limits.settle_tolerance_m``), the transient bounded by the static displacement jump from 0 V or
    ``limits.max_voltage_V``, at most ``limits.max_settle_s``):

    * ``"rest"`` before a step: at 0 V, at least ``limits.step_rest_min_s``;
    * ``"static"``: at ``voltage_V`` and ``mass_kg``, at least ``limits.static_hold_s`` less the measured
      ``limits.static_measure_s`` (the protocol's hold_s = settle + measure);
    * ``"sine"``: at the mean u^2 (u_eff = sqrt(amplitude^2 / 2 + offset^2): the creep sees the mean
      Maxwell pressure), or the periodic orbit's own slowest time constant where it is slower
      (``orbit_time_constant_s``, from its Floquet multipliers: near a resonance or a fold the approach
      to the orbit is slower than any time constant at rest;
      :func:`~dea_ros.solvers.sweep.orbit_time_constants`), at least ``limits.settle_s``.

    Where eq. 20 has no equilibrium at the operating point the cap is held, with a warning."""
    umax = limits.max_voltage_V
    u, floor = {"rest": (0.0, limits.step_rest_min_s),
                "static": (voltage_V, max(limits.static_hold_s - limits.static_measure_s, 0.0)),
                "sine": (math.sqrt(amplitude_V ** 2 / 2 + offset_V ** 2), limits.settle_s)}[kind]
    cap = max(limits.max_settle_s, floor)
    try:
        return settle_time(params, u, (0.0, umax), limits.settle_tolerance_m, cap, floor, mass_kg,
                           orbit_time_constant_s)
    except DeaRosError:
        return SettleTime(u, params.mass_kg if mass_kg is None else float(mass_kg), math.inf, math.nan,
                          limits.settle_tolerance_m, math.inf, cap, cap)


def step_rest_s(params: MembraneParameters, limits: PlanLimits | None = None) -> float:
    """Rest at 0 V before a step so it starts from rest as the step fit assumes (:func:`record_settle`,
    ``"rest"``), s."""
    return record_settle(params, limits or PlanLimits(), "rest").settle_s


def _settle_fields(settle: SettleTime, what: str = "") -> dict:
    what = what or f"the hold at {settle.voltage_V:.0f} V ({settle.mass_kg * 1e3:.3g} g)"
    warning = settle.warning(what) or ("" if math.isfinite(settle.amplitude_m) else
                                       f"{what}: no static equilibrium at {settle.voltage_V:.0f} V, held "
                                       f"{settle.settle_s:.3g} s; the record may be measured before it settled")
    left = (settle.residual_m if math.isfinite(settle.amplitude_m) else math.inf) if settle.capped else 0.0
    return {"settle_s": settle.settle_s, "time_constant_s": settle.time_constant_s, "settle_warning": warning,
            "transient_left_m": left}


def candidate_records(params: MembraneParameters, limits: PlanLimits | None = None) -> list:
    """Every candidate within the limits: sines (amplitude x frequency, slew-limited: U w <= slew),
    steps from 0 V, static points at the dynamic mass and at 0 V / full voltage on the other masses."""
    limits = limits or PlanLimits()
    umax = limits.max_voltage_V
    out = []
    shapes = [(a * umax, 0.0) for a in limits.amplitude_fractions]
    if limits.offsets:
        shapes.append((umax / 2, umax / 2))
    grid = _frequency_grid(params, limits)
    for amp, off in shapes:
        what = f"the settle of the {amp:.0f} V{f' + {off:.0f} V offset' if off else ''} sine"
        at_rest = record_settle(params, limits, "sine", amplitude_V=amp, offset_V=off)
        freqs = [float(f) for f in grid if amp * 2 * math.pi * f <= limits.slew_rate_V_per_s]
        orbit = orbit_time_constants(params, SinePeriodic(amp, 1.0, off), freqs, stable_only=True) if freqs else {}
        for f in freqs:
            tau = orbit.get(round(f, 3), 0.0)
            settle = at_rest if not tau > at_rest.time_constant_s else \
                record_settle(params, limits, "sine", amplitude_V=amp, offset_V=off, orbit_time_constant_s=tau)
            fields = _settle_fields(settle, f"{what} at {f:.3g} Hz")
            dur, n = sine_record_cost(limits, f, fields["settle_s"])
            out.append(CandidateRecord("sine", dur, params.mass_kg, f, float(amp), float(off), measured_samples=n,
                                       **fields))
    rest = _settle_fields(record_settle(params, limits, "rest"), "the rest at 0 V before a step")
    for a in limits.step_fractions:
        out.append(CandidateRecord("step", rest["settle_s"] + limits.step_pre_s + limits.step_hold_s, params.mass_kg,
                                   final_V=float(a * umax), **rest))
    n_static = int(round(limits.static_measure_s * limits.sample_rate_Hz))
    levels = [(params.mass_kg, a * umax) for a in limits.static_fractions]
    levels += [(float(m), u) for m in limits.other_masses_kg for u in (0.0, umax)]
    for m, u in levels:
        hold = _settle_fields(record_settle(params, limits, "static", voltage_V=u, mass_kg=m))
        out.append(CandidateRecord("static", hold["settle_s"] + limits.static_measure_s, float(m), voltage_V=float(u),
                                   measured_samples=n_static, **hold))
    return out


def _objective_for(first: FirstFit, record: CandidateRecord, limits: PlanLimits) -> JointObjective:
    """The joint refinement's objective over this one record (the data are placeholders: only the
    Jacobian is used), parametrised as the first fit."""
    names = first.names
    curvature = curvature_mode(names)
    slope = "sigma_h'(1)_Pa" in names
    p = first.parameters
    noise = first.laser_noise_m
    left = record.transient_left_m      # an unsettled record's leftover transient: an error beyond the noise
    static, steps, points, rms_sigma = None, [], [], []
    if record.kind == "sine":
        excitation = SinePeriodic(record.amplitude_V, record.frequency_Hz, record.offset_V) if record.offset_V \
            else None
        # its RMS about its measured rest position, as the fit takes it (FrequencyPoint.rest_d0_m): the rest's
        # error cancels, so neither its uncertainty nor its move with the parameters enters the information
        rest_m = float(static_equilibrium(p.replace(mass_kg=record.mass_kg), 0.0).displacement_m)
        points = [FrequencyPoint(record.frequency_Hz, record.amplitude_V, 0.0, record.mass_kg, record.label(),
                                 periodic_input=excitation, rest_d0_m=rest_m)]
        rms_sigma = [math.hypot(noise / math.sqrt(max(record.measured_samples, 1)), left)]
    elif record.kind == "step":
        t = np.arange(0.0, limits.step_pre_s + limits.step_hold_s, 1.0 / limits.sample_rate_Hz)
        u = np.where(t < limits.step_pre_s, 0.0, record.final_V)
        steps = [StepData(t, u, np.zeros_like(t), record.mass_kg, "zoh", record.label())]
    else:
        static = StaticData(np.array([record.mass_kg]), np.array([record.voltage_V]), np.zeros(1), record.label())
    static_sigma = first.static_sigma_m if math.isfinite(first.static_sigma_m) and first.static_sigma_m > 0 \
        else noise / math.sqrt(max(record.measured_samples, 1))
    obj = JointObjective(p, static, steps, points, math.hypot(static_sigma, left),
                         [math.hypot(noise, left)] * len(steps), rms_sigma, fit_curvature=curvature, fit_slope=slope)
    if obj.names != first.names:
        raise PlanningError(f"the candidate's parameters {obj.names} differ from the first fit's {first.names}")
    return obj


def candidate_information(first: FirstFit, candidates, limits: PlanLimits | None = None) -> tuple:
    """([(candidate, G_c in relative units)], notes): the information each record adds (module docstring);
    candidates whose model response cannot be computed are left out and named in the notes."""
    limits = limits or PlanLimits()
    scale = first.scale()
    out, notes = [], []
    for c in candidates:
        if not math.isfinite(c.transient_left_m):
            notes.append(f"{c.label()}: left out (the membrane is not stable there at the first fit: it would be "
                         "measured before it settles)")
            continue
        try:
            obj = _objective_for(first, c, limits)
            jac = obj.physical_jacobian(obj.theta0()) * scale[None, :]
        except PlanningError:
            raise
        except (DeaRosError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
            notes.append(f"{c.label()}: left out ({exc})")
            continue
        if np.all(np.isfinite(jac)):
            out.append((c, jac.T @ jac))
        else:
            notes.append(f"{c.label()}: left out (non-finite sensitivities)")
    return out, notes


def _widths(first: FirstFit, info_rel: np.ndarray) -> np.ndarray:
    diag = inverse_diagonal(info_rel)
    w = T95 * np.sqrt(first.variance_factor * np.where(np.isfinite(diag), diag, np.inf))
    return np.where(np.isfinite(w), w, np.inf)


def _criterion(widths: np.ndarray, idx, kind: str) -> float:
    w = np.minimum(widths[idx], WIDTH_CAP)
    return float(np.sum(np.log(w))) if kind == "widths" else float(np.sum(w ** 2))


def _pair_correlation(cov: np.ndarray, i: int, j: int) -> float:
    den = math.sqrt(max(cov[i, i] * cov[j, j], 0.0))
    return float(cov[i, j] / den) if den > 0 else float("nan")


def _correlations(first: FirstFit, info_rel: np.ndarray) -> dict:
    out = {}
    cov = np.linalg.pinv(info_rel, rcond=SINGULAR_EIGENVALUE_RATIO)
    for a, b, label in (("eta1_Pa_s", "eta2_Pa_s", "eta1/eta2"), ("k1_Pa", "eta1_Pa_s", "k1/eta1"),
                        ("eps_r", "sigma_h''(1)_Pa", "eps_r/sigma_h''(1)")):
        if a in first.names and b in first.names:
            out[label] = _pair_correlation(cov, first.names.index(a), first.names.index(b))
    return out


def _goal_correlation(info_rel: np.ndarray, pairs) -> float:
    """The largest |correlation| among ``pairs`` (index pairs) at ``info_rel`` (0 without pairs)."""
    if not pairs:
        return 0.0
    cov = np.linalg.pinv(info_rel, rcond=SINGULAR_EIGENVALUE_RATIO)
    return max(abs(np.nan_to_num(_pair_correlation(cov, i, j))) for i, j in pairs)


def fit_widths(first: FirstFit) -> tuple:
    """(relative 95 % half-widths, pair correlations) of a fit from its own Fisher information (the planner's
    "before"; of a two-pass fit: the realised widths, comparable with a plan's expected ones)."""
    scale = first.scale()
    info = first.information * np.outer(scale, scale)
    return dict(zip(first.names, map(float, _widths(first, info)))), _correlations(first, info)


def _greedy_picks(first: FirstFit, information: list, info: np.ndarray, idx: list, criterion: str, budget_s: float,
                  max_records: int, max_correlation: float | None, notes: list) -> tuple:
    """(picks, information after them) of :func:`plan_experiments`' greedy selection (module docstring): while
    the goal pair's expected |correlation| is above ``max_correlation``, the record that lowers it most per
    second; then the largest decrease of the criterion per second among the records that keep it there."""
    goal = 1.0 if max_correlation is None else float(max_correlation)
    pairs = [(first.names.index(a), first.names.index(b)) for a, b in CORRELATION_GOAL_PAIRS
             if a in first.names and b in first.names] if goal < 1.0 else []
    picks, used, spent = [], set(), 0.0
    current = _criterion(_widths(first, info), idx, criterion)
    threshold = MIN_DECREASE if criterion == "widths" else MIN_DECREASE * current
    while len(picks) < max_records:
        correlation = _goal_correlation(info, pairs)
        decorrelate = correlation > goal
        best = None
        for k, (c, g) in enumerate(information):
            if k in used or spent + c.duration_s > budget_s + 1e-9:
                continue
            value = _criterion(_widths(first, info + g), idx, criterion)
            after_correlation = _goal_correlation(info + g, pairs)
            if decorrelate:
                gain, enough = correlation - after_correlation, MIN_DECREASE
            elif after_correlation > goal:
                continue
            else:
                gain, enough = current - value, threshold
            if gain > enough and (best is None or gain / c.duration_s > best[0]):
                best = (gain / c.duration_s, k, value)
        if best is None and decorrelate:
            goal = 1.0                       # nothing lowers it: the criterion alone from here
            names = ", ".join(f"{a}/{b}" for a, b in CORRELATION_GOAL_PAIRS)
            notes.append(f"no record within the budget lowers the {names} correlation below {max_correlation:g} "
                         f"(expected {correlation:.3f}); planned for the widths alone")
            continue
        if best is None:
            break
        _rate, k, value = best
        c, g = information[k]
        info = info + g
        used.add(k)
        spent += c.duration_s
        gain, current = current - value, value
        after = dict(zip(first.names, map(float, _widths(first, info))))
        picks.append(PlannedRecord(c, gain, gain / c.duration_s, after))
    return picks, info


def plan_experiments(first: FirstFit, budget_s: float = 60.0, limits: PlanLimits | None = None,
                     candidates=None, targets=None, criterion: str = "widths", max_records: int = 12,
                     information=None, max_correlation: float | None = DEFAULT_MAX_CORRELATION) -> ExperimentPlan:
    """Greedy Fisher-information plan (module docstring): the records that shrink the target intervals
    most per second of experiment time, within ``budget_s`` seconds, the correlation goal
    (``max_correlation`` for ``CORRELATION_GOAL_PAIRS``) first. ``information``: precomputed
    :func:`candidate_information` (then ``candidates`` is ignored)."""
    if not (isinstance(budget_s, (int, float)) and math.isfinite(budget_s) and budget_s > 0):
        raise PlanningError(f"budget_s must be a positive number of seconds, got {budget_s!r}")
    if criterion not in ("widths", "A"):
        raise PlanningError(f"criterion must be 'widths' or 'A', got {criterion!r}")
    if max_correlation is not None and not (isinstance(max_correlation, (int, float)) and 0 < max_correlation <= 1):
        raise PlanningError(f"max_correlation must lie in (0, 1] (1 or None: no correlation goal), got "
                            f"{max_correlation!r}")
    limits = limits or PlanLimits()
    targets = tuple(n for n in (targets or DEFAULT_TARGETS) if n in first.names)
    if not targets:
        raise PlanningError(f"no target parameter is among the first fit's {first.names}")
    idx = [first.names.index(n) for n in targets]
    notes = [f"the first fit warned: {w}; the plan is linearised at that fit, which may be wrong: check it "
             "(more data where it is doubtful, another start) before trusting the plan" for w in first.warnings]
    if information is None:
        cands = candidate_records(first.parameters, limits) if candidates is None else list(candidates)
        information, left_out = candidate_information(first, cands, limits)
        notes += left_out
    if not information:
        raise PlanningError("no candidate experiment within the limits could be evaluated")
    scale = first.scale()
    info = first.information * np.outer(scale, scale)
    before = _widths(first, info)
    picks, info = _greedy_picks(first, information, info, idx, criterion, budget_s, max_records, max_correlation,
                                notes)
    after = _widths(first, info)
    cheapest = min((c for c, _g in information), key=lambda c: c.duration_s)
    if not picks and cheapest.duration_s > budget_s:
        notes.append(f"every candidate takes longer than the {budget_s:g} s budget with its hold until it settles "
                     f"(the cheapest, {cheapest.label()}, {cheapest.duration_s:.1f} s, held {cheapest.settle_s:.1f} "
                     "s): raise the budget, or cap the holds (PlanLimits.max_settle_s, a protocol's "
                     "adaptive_max_settle_s) and measure unsettled")
    elif not picks:
        notes.append("no candidate within the budget shrinks the target intervals")
    notes += list(dict.fromkeys(p.record.settle_warning for p in picks if p.record.settle_warning))
    return ExperimentPlan(first.names, targets, criterion, float(budget_s), dict(zip(first.names, map(float, before))),
                          dict(zip(first.names, map(float, after))),
                          _correlations(first, first.information * np.outer(scale, scale)),
                          _correlations(first, info), picks, len(information), first.source, notes,
                          None if max_correlation is None else float(max_correlation))


def plan_protocol(plan: ExperimentPlan, base: Protocol, limits: PlanLimits | None = None) -> Protocol:
    """The planned records as a protocol the identifier node runs (the mass and membrane of ``base``):
    steps from 0 V after a rest, static levels, sines grouped by amplitude, offset and hold, then 0 V, each
    held its record's ``settle_s`` (:func:`record_settle`) before it is measured (before session 22 a group
    held every frequency for its longest hold: the pass ran longer than the plan's cost). Static points at
    another mass cannot be run without changing the mass by hand: they are left out (PlanningError if
    nothing else is left)."""
    limits = limits or PlanLimits()
    segments = []
    shapes: dict = {}
    for p in plan.picks:
        r = p.record
        if r.kind == "sine":     # one segment per shape and hold: each frequency of a segment is held its settle_s
            shapes.setdefault((r.amplitude_V, r.offset_V, r.settle_s), []).append(r)
        elif r.kind == "step":
            segments.append({"kind": "rest", "hold_s": r.settle_s})
            segments.append({"kind": "step", "initial_V": 0.0, "final_V": r.final_V, "pre_s": limits.step_pre_s,
                             "hold_s": limits.step_hold_s})
        elif abs(r.mass_kg - base.mass_kg) < 1e-9:
            segments.append({"kind": "static", "voltages_V": [r.voltage_V],
                             "hold_s": r.settle_s + limits.static_measure_s,
                             "measure_s": limits.static_measure_s})
    for (amp, off, settle), picks in sorted(shapes.items(),
                                            key=lambda kv: (kv[0][:2], min(r.frequency_Hz for r in kv[1]))):
        segments.append({"kind": "sine", "amplitude_V": amp, "offset_V": off,
                         "frequencies_Hz": sorted(r.frequency_Hz for r in picks), "settle_s": settle,
                         "measure_s": limits.measure_s})
    if not segments:
        raise PlanningError("no planned record can run at the protocol's mass")
    segments.append({"kind": "rest", "hold_s": 1.0})
    return Protocol.from_dict({"name": f"{base.name}-planned", "membrane": base.membrane, "mass_kg": base.mass_kg,
                               "segments": segments}, source=f"{base.source} (planned second pass)")
