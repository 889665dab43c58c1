"""What a study computes per design: static stroke, resonance peak, folds, bands, failures.

Each design is a base membrane with some fields replaced and an excitation. Its row holds the
varied values, the static stroke over the voltage range (eq. 20), the resonance peak of the
frequency sweep (located on the branch, :meth:`~dea_ros.solvers.sweep_results.SweepResult.resonance_peak`),
the folds, the bifurcations by kind and the bands of the realised response (torus =
quasi-periodic, period-doubled, coexisting) with their total widths, or a failure with its
reason:

* ``breakdown limit``: the peak voltage exceeds ``breakdown_margin`` x breakdown field x z0
  (the design is not computed: the membrane would not survive the excitation);
* ``no equilibrium``: no static equilibrium up to d = l0 (electromechanical instability);
* ``no convergence``: the harmonic-balance continuation failed;
* ``invalid parameters``: the design is not a valid or plausible membrane (e.g. f_max <= f_min);
* ``error``: anything else (the message says what; the study goes on).

The sweep is the public :func:`~dea_ros.solvers.sweep.frequency_sweep`, so any speed-up
of the solver reaches the study unchanged. Rows have a fixed set of columns (:data:`COLUMNS`);
lists (folds, bands) are JSON text so that CSV and Parquet hold the same values.
"""
from __future__ import annotations

import contextlib
import gc
import json
import math

import numpy as np

from ..errors import ContinuationError, HarmonicBalanceError, NoEquilibriumError, ParameterError
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..solvers import SinePeriodic, frequency_sweep
from .spec import EXCITATION_FIELDS, StudySpec, parse_spec

__all__ = ["design_parameters", "evaluate_design", "evaluate_chunk", "COLUMNS", "FAILURE_REASONS",
           "result_columns"]

FAILURE_REASONS = ("breakdown limit", "no equilibrium", "no convergence", "invalid parameters", "error")

#: Result columns after the design index and the varied parameters, with their types.
COLUMNS = (
    ("status", str), ("failure", str), ("message", str),
    ("peak_voltage_V", float), ("safe_voltage_V", float),
    ("d0_m", float), ("stroke_m", float), ("static_stiffness_min_N_per_m", float),
    ("peak_frequency_Hz", float), ("peak_d_rms_m", float), ("peak_stable", bool),
    ("branch_peak_frequency_Hz", float), ("branch_peak_d_rms_m", float),
    ("n_folds", int), ("folds_Hz", str), ("hysteresis", bool),
    ("n_torus", int), ("n_period_doubling", int),
    ("quasi_periodic_width_Hz", float), ("period_doubled_width_Hz", float), ("coexisting_width_Hz", float),
    ("first_quasi_periodic_Hz", float), ("first_period_doubled_Hz", float),
    ("bands", str), ("max_truncation_ratio", float), ("warning", str),
)


def result_columns(spec: StudySpec) -> list:
    """All column names of a study's results, in order."""
    return ["design"] + spec.names + [c for c, _t in COLUMNS]


def design_parameters(base: MembraneParameters, spec: StudySpec, values) -> tuple:
    """(membrane parameters, excitation dict) of one design (``values`` in the order of ``spec.names``).

    ``prestretch_rule: ogden`` (default) rescales the Ogden coefficients with the prestretch as eqs. 8-9
    do for fixed material constants mu_i: beta_i ~ lambda_p^(2i), gamma_i ~ lambda_p^(-4i); ``fixed``
    keeps beta, gamma (then only the geometry sees the prestretch)."""
    changes = {}
    excitation = dict(spec.excitation)
    for name, value in zip(spec.names, values):
        if name in EXCITATION_FIELDS:
            excitation[name] = float(value)
        else:
            changes[name] = float(value)
    if "prestretch" in changes and spec.prestretch_rule == "ogden":
        r = changes["prestretch"] / base.prestretch
        changes["beta_Pa"] = tuple(b * r ** (2 * (i + 1)) for i, b in enumerate(base.beta_Pa))
        changes["gamma_Pa"] = tuple(g * r ** (-4 * (i + 1)) for i, g in enumerate(base.gamma_Pa))
    params = base.replace(name=f"{base.name} (study design)", **changes)
    return params, excitation


def _empty_row(index: int, spec: StudySpec, values) -> dict:
    row = {"design": int(index)}
    row.update({n: float(v) for n, v in zip(spec.names, values)})
    for col, typ in COLUMNS:
        row[col] = "" if typ is str else (False if typ is bool else (0 if typ is int else float("nan")))
    row["status"] = "ok"
    return row


def _fail(row: dict, reason: str, message: str) -> dict:
    row["status"] = "failed"
    row["failure"] = reason
    row["message"] = message[:500]
    return row


def _bands_summary(row: dict, sweep) -> None:
    widths = {"quasi-periodic": 0.0, "period-doubled": 0.0, "coexisting": 0.0}
    first = {"quasi-periodic": float("nan"), "period-doubled": float("nan")}
    bands = []
    for b in sweep.bands:
        bands.append([b.kind, float(b.f_start_Hz), float(b.f_end_Hz)])
        if b.kind in widths:
            widths[b.kind] += float(b.f_end_Hz - b.f_start_Hz)
        if b.kind in first and not math.isfinite(first[b.kind]):
            first[b.kind] = float(b.f_start_Hz)
    row["quasi_periodic_width_Hz"] = widths["quasi-periodic"]
    row["period_doubled_width_Hz"] = widths["period-doubled"]
    row["coexisting_width_Hz"] = widths["coexisting"]
    row["first_quasi_periodic_Hz"] = first["quasi-periodic"]
    row["first_period_doubled_Hz"] = first["period-doubled"]
    row["bands"] = json.dumps(bands)


def evaluate_design(base: MembraneParameters, spec: StudySpec, index: int, values) -> dict:
    """The result row of one design (module docstring); never raises for a bad design."""
    row = _empty_row(index, spec, values)
    try:
        params, exc = design_parameters(base, spec, values)
        params.check_plausible("design")
    except (ParameterError, ValueError) as err:
        return _fail(row, "invalid parameters", str(err))
    amp, offset = exc["amplitude_V"], exc["offset_V"]
    f_min, f_max = exc["f_min_Hz"], exc["f_max_Hz"]
    if not f_max > f_min > 0:
        return _fail(row, "invalid parameters", f"f_max_Hz ({f_max:g}) must be larger than f_min_Hz ({f_min:g}) > 0")
    peak_v = abs(offset) + abs(amp)
    static_max = spec.static_max_V if spec.static_max_V is not None else peak_v
    row["peak_voltage_V"] = float(max(peak_v, static_max))
    safe = params.max_safe_voltage_V(spec.breakdown_margin)
    row["safe_voltage_V"] = float(safe)
    if row["peak_voltage_V"] > safe:
        return _fail(row, "breakdown limit", f"peak voltage {row['peak_voltage_V']:.0f} V exceeds "
                     f"{spec.breakdown_margin:g} x breakdown voltage = {safe:.0f} V "
                     f"(field {params.breakdown_field_V_per_m:g} V/m x z0 {params.thickness_m:g} m)")
    try:
        volts = np.linspace(0.0, static_max, spec.static_voltages)
        eq = static_equilibrium(params, volts)
        d = np.asarray(eq.displacement_m, float)
        row["d0_m"] = float(d[0])
        row["stroke_m"] = float(np.max(np.abs(d - d[0])))
        row["static_stiffness_min_N_per_m"] = float(np.min(eq.stiffness_N_per_m))
        if spec.sweep["spacing"] == "log":
            freqs = np.geomspace(f_min, f_max, spec.sweep["points"])
        else:
            freqs = np.linspace(f_min, f_max, spec.sweep["points"])
        sweep = frequency_sweep(params, SinePeriodic(amp, f_min, offset_V=offset), freqs,
                                n_harmonics=spec.sweep["harmonics"], stability=spec.sweep["stability"],
                                branch_switching=spec.sweep["branch_switching"], realised=spec.sweep["realised"])
    except NoEquilibriumError as err:
        return _fail(row, "no equilibrium", str(err))
    except (HarmonicBalanceError, ContinuationError, np.linalg.LinAlgError, FloatingPointError) as err:
        return _fail(row, "no convergence", f"{type(err).__name__}: {err}")
    except (ParameterError, ValueError) as err:
        return _fail(row, "invalid parameters", str(err))
    except Exception as err:  # noqa: BLE001 - one bad design must not stop a study of thousands
        return _fail(row, "error", f"{type(err).__name__}: {err}")
    peak, tip = sweep.resonance_peak(True), sweep.resonance_peak(False)
    row["peak_frequency_Hz"] = float(peak["frequency_Hz"])
    row["peak_d_rms_m"] = float(peak["d_rms_m"])
    row["peak_stable"] = bool(peak.get("stable", False))
    row["branch_peak_frequency_Hz"] = float(tip["frequency_Hz"])
    row["branch_peak_d_rms_m"] = float(tip["d_rms_m"])
    row["n_folds"] = len(sweep.folds)
    row["folds_Hz"] = json.dumps([float(f.frequency_Hz) for f in sweep.folds])
    row["hysteresis"] = len(sweep.folds) >= 2
    kinds = [b.kind for b in sweep.bifurcations]
    row["n_torus"] = kinds.count("torus")
    row["n_period_doubling"] = kinds.count("period-doubling")
    _bands_summary(row, sweep)
    ratio = float(sweep.max_truncation_ratio)
    row["max_truncation_ratio"] = ratio
    if ratio > 1e-2:
        row["warning"] = (f"the highest harmonic reaches {ratio:.2g} of the dominant one: raise "
                          f"sweep.harmonics ({spec.sweep['harmonics']})")
    return row


@contextlib.contextmanager
def _full_collections_skip_older_objects():
    """Python's full garbage collections skip the objects alive at entry (gc.freeze) until exit
    (gc.unfreeze: they are collectable again, nothing leaks). A design creates and frees thousands of
    objects; each full collection otherwise scans the ~150,000 objects of the imported libraries
    (measured: ~1.5 ms a design in this process, more in a Dask worker)."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def evaluate_chunk(task: dict) -> list:
    """Rows of a batch of designs: ``task`` = {"spec": raw spec, "source", "base": base parameters dict,
    "designs": [[index, [values...]], ...]} (plain data, so it travels to any worker)."""
    spec = parse_spec(task["spec"], task.get("source", "spec"))
    base = MembraneParameters(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in task["base"].items()})
    with _full_collections_skip_older_objects():
        return [evaluate_design(base, spec, int(i), vals) for i, vals in task["designs"]]
