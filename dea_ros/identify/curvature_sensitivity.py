"""How the predictions depend on the value written for a curvature sigma_h''(1) the data do not determine.

When sigma_h''(1) (eq. 10, derivative in s = lambda_r^2) is not identified, the reported parameters
and intervals come from the fit in which it is free (:mod:`~dea_ros.identify.refinement`), and
params.yaml must still carry one value for the model to run (the free fit's, a representative). To
say what that choice means, :func:`curvature_sensitivity` evaluates the model with the curvature at
both ends of its 95 % interval (clipped to the plausible range of the search, +-``CURVATURE_BOUND_PA``)
and every other parameter as written: the resonance peak of the frequency response (frequency and
RMS, eq. 21, located on the branch at the amplitude of the largest sine record) and the step
response of every step record (largest difference from the written model's).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import DeaRosError
from ..model.parameters import MembraneParameters
from ..solvers.inputs import SinePeriodic
from ..solvers.sweep import frequency_sweep
from .experiments import ExperimentSet
from .joint_fit import CURVATURE_BOUND_PA
from .static_fit import EXTENDED_COMBINATION_MATRIX, OgdenRepresentation
from .step_simulation import simulate_step

__all__ = ["CurvatureSensitivity", "with_curvature", "curvature_sensitivity"]

_ENDS = ("low", "written", "high")


@dataclass
class CurvatureSensitivity:
    """The model's predictions with sigma_h''(1) at the ends of its interval and as written."""

    curvature_Pa: dict                   # "low", "written", "high" -> sigma_h''(1) (Pa, derivative in s)
    amplitude_V: float | None            # the sine amplitude of the peaks
    peak_frequency_Hz: dict = field(default_factory=dict)   # end -> resonance peak frequency (nan: failed)
    peak_d_rms_m: dict = field(default_factory=dict)        # end -> RMS at the peak (eq. 21)
    #: end -> largest |d(t) - d_written(t)| over the step records (m)
    step_max_difference_m: dict = field(default_factory=dict)
    clipped: bool = False                # an end was clipped to the plausible range
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"curvature_Pa": dict(self.curvature_Pa), "amplitude_V": self.amplitude_V,
                "peak_frequency_Hz": dict(self.peak_frequency_Hz), "peak_d_rms_m": dict(self.peak_d_rms_m),
                "step_max_difference_m": dict(self.step_max_difference_m), "clipped": self.clipped,
                "notes": list(self.notes)}


def with_curvature(params: MembraneParameters, curvature_Pa: float) -> MembraneParameters:
    """``params`` with sigma_h''(1) = ``curvature_Pa`` and sigma_h(1), sigma_h'(1), sigma_h'''(1) kept
    (the (beta, gamma) closest to ``params``')."""
    bg = np.r_[params.beta_Pa, params.gamma_Pa]
    c = EXTENDED_COMBINATION_MATRIX @ bg
    rep = OgdenRepresentation(params.prestretch, 4, bg, matrix=EXTENDED_COMBINATION_MATRIX)
    new = rep.beta_gamma([c[0], c[1], float(curvature_Pa), c[3]])
    return params.replace(beta_Pa=tuple(float(v) for v in new[:3]), gamma_Pa=tuple(float(v) for v in new[3:]))


def _peak_grid(experiments: ExperimentSet):
    """(amplitude, mass, frequencies) around the largest measured RMS of the sine records."""
    best = None
    for sine in experiments.sines:
        k = int(np.argmax(sine.d_rms_m))
        if best is None or sine.d_rms_m[k] > best[0]:
            best = (float(sine.d_rms_m[k]), float(sine.amplitude_V[k]), sine.mass_kg, float(sine.frequency_Hz[k]))
    if best is None:
        return None
    _rms, amp, mass, f = best
    return amp, mass, np.linspace(0.6 * f, 1.4 * f, 33)


def _peak(params: MembraneParameters, amplitude_V: float, freqs, n_harmonics: int) -> tuple:
    sweep = frequency_sweep(params, SinePeriodic(amplitude_V, 1.0), freqs, n_harmonics=n_harmonics,
                            branch_switching=False, realised=False)
    pk = sweep.resonance_peak()
    return float(pk["frequency_Hz"]), float(pk["d_rms_m"])


def _steps(params: MembraneParameters, experiments: ExperimentSet) -> list:
    return [simulate_step(params, st) for st in experiments.steps]


def _ends(statistics, written: float) -> tuple:
    """(low, high) of sigma_h''(1)'s 95 % interval within +-CURVATURE_BOUND_PA; whether clipped."""
    i = statistics.names.index("sigma_h''(1)_Pa")
    lo, hi = float(statistics.ci_low[i]), float(statistics.ci_high[i])
    if not (math.isfinite(lo) and math.isfinite(hi)):
        lo, hi = -CURVATURE_BOUND_PA, CURVATURE_BOUND_PA
    c_lo, c_hi = max(lo, -CURVATURE_BOUND_PA), min(hi, CURVATURE_BOUND_PA)
    return min(c_lo, written), max(c_hi, written), (c_lo != lo or c_hi != hi)


def curvature_sensitivity(params: MembraneParameters, statistics, experiments: ExperimentSet,
                          n_harmonics: int = 8) -> CurvatureSensitivity:
    """The predictions of ``params`` with sigma_h''(1) at the ends of its interval in ``statistics``
    (module docstring); a prediction the model cannot make there is nan with a note."""
    written = float(EXTENDED_COMBINATION_MATRIX[2] @ np.r_[params.beta_Pa, params.gamma_Pa])
    lo, hi, clipped = _ends(statistics, written)
    values = {"low": lo, "written": written, "high": hi}
    grid = _peak_grid(experiments)
    out = CurvatureSensitivity(values, grid[0] if grid else None, clipped=clipped)
    if clipped:
        out.notes.append(f"the interval reaches beyond the plausible range +-{CURVATURE_BOUND_PA / 1e3:.6g} kPa "
                         "of the search: its ends are clipped to it")
    reference = None
    for end in _ENDS[1:2] + _ENDS[0:1] + _ENDS[2:]:      # the written model first: the steps compare with it
        p = with_curvature(params, values[end])
        try:
            if grid is not None:
                amp, mass, freqs = grid
                out.peak_frequency_Hz[end], out.peak_d_rms_m[end] = _peak(p.replace(mass_kg=mass), amp, freqs,
                                                                          n_harmonics)
        except (DeaRosError, ArithmeticError, ValueError) as exc:
            out.peak_frequency_Hz[end] = out.peak_d_rms_m[end] = float("nan")
            out.notes.append(f"{end} end: no resonance peak computed ({exc})")
        try:
            steps = _steps(p, experiments)
            if end == "written":
                reference = steps
            if steps and reference is not None:
                out.step_max_difference_m[end] = max(float(np.max(np.abs(a - b))) for a, b in zip(steps, reference))
        except (DeaRosError, ArithmeticError, ValueError) as exc:
            out.step_max_difference_m[end] = float("nan")
            out.notes.append(f"{end} end: no step response computed ({exc})")
    return out
