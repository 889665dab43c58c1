"""The outcome of an identification: fitted parameters, the fits, the evaluation, warnings and timings.

:class:`IdentificationResult` is what :func:`~dea_ros.identify.pipeline.identify` returns; the
report (params.yaml, report.md, the figures) and the CLI's JSON (:meth:`IdentificationResult.to_dict`,
result.json) are views of it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..model.parameters import MembraneParameters
from .dynamic_fit import DynamicFitResult
from .evaluation import Evaluation
from .experiments import ExperimentSet
from .joint_fit import JointFitResult
from .jsonable import jsonable
from .metrics import linear_combination_ci
from .static_fit import StaticFitResult, stress_combinations

__all__ = ["IdentificationResult", "reported_statistics"]


def reported_statistics(joint, two_stage_linearisation, dynamic):
    """The statistics of the reported parameters: the joint refinement's; without one, the joint objective's
    linearised at the two-stage result; else the dynamic fit's (conditional on the static stage); None."""
    for fit in (joint, two_stage_linearisation, dynamic):
        if fit is not None:
            return fit.statistics
    return None


@dataclass
class IdentificationResult:
    """Fitted parameters, the fits, the evaluation against the data, warnings and timings."""

    experiments: ExperimentSet
    parameters: MembraneParameters
    static: StaticFitResult | None
    dynamic: DynamicFitResult | None
    #: the fitted model against every experiment (empty when the identification did not evaluate)
    evaluation: Evaluation
    timings_s: dict
    warnings: list = field(default_factory=list)
    options: dict = field(default_factory=dict)
    joint: JointFitResult | None = None
    classification: list = field(default_factory=list)   # one entry per sine record (see classify_records)
    #: no joint refinement (rejected or failed): the joint objective linearised at the reported two-stage
    #: result (:func:`~dea_ros.identify.joint_fit.fit_joint`, ``minimise`` False); its statistics are the
    #: reported intervals
    two_stage_linearisation: JointFitResult | None = None
    #: sigma_h''(1): True identified (written), False not identified (base value written), None not fitted
    curvature_identified: bool | None = None
    curvature_written_Pa: float | None = None
    curvature_status: str = "not fitted"   # "identified", "poorly determined", "not identified", "not fitted"
    #: confidence bands of the frequency response (:class:`~dea_ros.identify.uncertainty.ResponseBand`),
    #: one per sine data set and amplitude, when asked for (``uncertainty_samples``)
    uncertainty: list = field(default_factory=list)
    #: per parameter of the final fit: status, 95 % interval, the records that determine it
    #: (:class:`~dea_ros.identify.determination.ParameterDetermination`)
    determination: list = field(default_factory=list)
    #: sigma_h''(1) not identified: the predictions with it at both ends of its interval
    #: (:class:`~dea_ros.identify.curvature_sensitivity.CurvatureSensitivity`)
    curvature_sensitivity: object = None
    #: the score test of the Ogden shape the refinement held beyond sigma_h'''(1)
    #: (:class:`~dea_ros.identify.joint_fit.ShapeTest`; None: not run); where it rejected, the reported fit has
    #: the whole shape free (its statistics name the fourth and fifth derivatives)
    shape_test: object = None

    @property
    def statistics(self):
        """The statistics of the final parameters (:func:`reported_statistics`)."""
        return reported_statistics(self.joint, self.two_stage_linearisation, self.dynamic)

    @property
    def slope_fitted(self) -> bool:
        """Whether sigma_h'(1) was a free parameter of the static fit or the joint refinement (one mass on
        the rig without a step or sine records holds it at the base value)."""
        fits = [f.statistics for f in (self.joint, self.static) if f is not None and f.statistics is not None]
        return any("sigma_h'(1)_Pa" in s.names for s in fits)

    def identification_metadata(self) -> dict:
        """What was identified and how (written next to the parameters in params.yaml).

        The hyperelastic stress is given at lambda_r = 1 with derivatives w.r.t. lambda_r as eq. 10 is
        written (the fits use s = lambda_r^2: d/dlambda = 2 d/ds, d2/dlambda2 = 2 d/ds + 4 d2/ds2).
        """
        c = stress_combinations(self.parameters.beta_Pa, self.parameters.gamma_Pa)
        stats = self.statistics
        s_stats = stats if (stats is not None and "sigma_h(1)_Pa" in stats.names) else (
            self.static.statistics if self.static is not None else None)

        def ci(st, weights):
            v = linear_combination_ci(st, weights)
            return None if v is None or not np.isfinite(v[3]) else [float(v[1]), float(v[2])]

        meta = {
            "method": "joint refinement (statistical weights)" if self.joint is not None else
                      f"two-stage (paper), weights {self.options.get('weights')}" + (
                          "; intervals: the joint objective linearised at the two-stage result (every parameter "
                          "free)" if self.two_stage_linearisation is not None else ""),
            "stress_derivatives": "w.r.t. lambda_r at lambda_r = 1 (eq. 10)",
            "sigma_h(1)_Pa": float(c[0]),
            "sigma_h(1)_Pa_ci95": ci(s_stats, {"sigma_h(1)_Pa": 1.0}),
            "dsigma_h_dlambda(1)_Pa": float(2.0 * c[1]),
            "dsigma_h_dlambda(1)_Pa_ci95": ci(s_stats, {"sigma_h'(1)_Pa": 2.0}),
        }
        if self.curvature_identified:
            meta["d2sigma_h_dlambda2(1)_Pa"] = float(2.0 * c[1] + 4.0 * c[2])
            meta["d2sigma_h_dlambda2(1)_Pa_ci95"] = ci(stats, {"sigma_h'(1)_Pa": 2.0, "sigma_h''(1)_Pa": 4.0})
            meta["d2sigma_h_dlambda2(1)_status"] = self.curvature_status
        else:
            meta["d2sigma_h_dlambda2(1)_Pa"] = "not identified"
            meta["d2sigma_h_dlambda2(1)_written_Pa"] = float(2.0 * c[1] + 4.0 * c[2])
            if stats is not None and "sigma_h''(1)_Pa" in stats.names:
                meta["d2sigma_h_dlambda2(1)_Pa_ci95"] = ci(stats, {"sigma_h'(1)_Pa": 2.0, "sigma_h''(1)_Pa": 4.0})
                meta["d2sigma_h_dlambda2(1)_note"] = (
                    "not determined by the data: beta/gamma carry the value of the fit in which it is free, a "
                    "representative only; it does not steer the other parameters (their values and intervals "
                    "come from that fit); report.md shows the predictions at both ends of its interval")
            else:
                meta["d2sigma_h_dlambda2(1)_note"] = (
                    "not fitted: beta/gamma carry the static fit's representation (base parameters file, or "
                    "eqs. 8-9 without one), not a value determined by the data")
        if self.shape_test is not None:
            note = {"free": "the data contradict the shape held beyond sigma_h'''(1): refined with all six Ogden "
                            "coefficients free",
                    "held": "the fourth and fifth derivatives held at the base's (the score test does not reject "
                            "them)"}.get(self.shape_test.outcome,
                                         "the data contradict the shape held beyond sigma_h'''(1), but the fit with "
                                         "it free was not kept (the warnings say why): the held shape's parameters, "
                                         "with the intervals linearised there with the whole shape free")
            meta["ogden_shape"] = {**self.shape_test.as_dict(), "note": note}
        if self.determination:
            meta["parameters"] = {d.name: {"status": d.status, "ci95": [d.ci_low, d.ci_high],
                                           "determined_by": [r for r, _w in d.determined_by]}
                                  for d in self.determination}
        for name in ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s"):
            st = stats if (stats is not None and name in stats.names) else (
                self.static.statistics if (self.static is not None and name == "eps_r") else None)
            if st is not None and name in st.names:
                i = st.names.index(name)
                if np.isfinite(st.relative_ci[i]):
                    meta[f"{name}_ci95"] = [float(st.ci_low[i]), float(st.ci_high[i])]
        info = self.fisher_information()
        if info is not None:
            meta["fisher_information"] = info
        left_out = [c_["frequency_Hz"] for c_ in self.classification if c_.get("used") == "left out"]
        if left_out:
            meta["left_out_frequencies_Hz"] = [float(f) for f in left_out]
        pd = [c_["frequency_Hz"] for c_ in self.classification if c_.get("used") == "period-doubled"]
        if pd:
            meta["period_doubled_fits_Hz"] = [float(f) for f in pd]
        return meta

    def fisher_information(self) -> dict | None:
        """The joint fit's Fisher information F = J^T J (weighted Jacobian, statistics' units: Pa for the
        stress combinations in s, 1 for eps_r, ln for k1, eta1, eta2) with what an experiment planner needs
        to add records to it (:mod:`~dea_ros.identify.planning`); None without a joint fit."""
        joint = self.joint
        if joint is None or joint.jacobian is None:
            return None
        jac = np.asarray(joint.jacobian, float)
        step_s = [float(v) for v in joint.sigmas.get("step_m", [])]
        rms_s = [float(v) for v in joint.sigmas.get("rms_m", [])]
        return {"names": list(joint.names), "values": [float(v) for v in joint.statistics.values],
                "log_parameters": [n in ("k1_Pa", "eta1_Pa_s", "eta2_Pa_s") for n in joint.names],
                "matrix": (jac.T @ jac).tolist(), "variance_factor": float(joint.cost / max(joint.dof, 1)),
                "dof": int(joint.dof), "static_sigma_m": float(np.median(joint.sigmas.get("static_m", float("nan")))),
                "laser_noise_m": float(np.median(step_s)) if step_s else None,
                "rms_sigma_m_median": float(np.median(rms_s)) if rms_s else None,
                "mass_kg": float(self.parameters.mass_kg),
                "first_fit_warnings": [str(w) for w in joint.warnings if "bound" in str(w) or "converge" in str(w)],
                "note": "covariance = variance_factor * matrix^-1; read by dea-ros plan"}

    def to_dict(self) -> dict:
        """JSON-friendly summary: parameters, fits, metrics, statistics, warnings, timings."""
        out = {
            "membrane": self.parameters.name,
            "parameters": self.parameters.to_dict(),
            "options": dict(self.options),
            "metrics": self.evaluation.to_dict(),
            "timings_s": {k: float(v) for k, v in self.timings_s.items()},
            "warnings": list(self.warnings),
        }
        if self.static is not None:
            st = self.static
            out["static_fit"] = {
                "method": st.method,
                "representation": st.representation,
                "combinations_Pa": {"sigma_h(1)": float(st.combinations_Pa[0]),
                                    "sigma_h'(1)": float(st.combinations_Pa[1]),
                                    "sigma_h''(1)": float(st.combinations_Pa[2])},
                "statistics": st.statistics.as_dict(),
                "evaluations": st.n_evaluations,
                "errors_um": st.errors_um,
            }
        out["identification"] = jsonable(self.identification_metadata())
        out["classification"] = jsonable([{k: v for k, v in c.items() if k != "guess"}
                                          for c in self.classification])
        if self.joint is not None:
            out["joint_fit"] = jsonable(self.joint.as_dict())
        if self.determination:
            out["determination"] = jsonable({d.name: d.to_dict() for d in self.determination})
        if self.curvature_sensitivity is not None:
            out["curvature_sensitivity"] = jsonable(self.curvature_sensitivity.to_dict())
        if self.uncertainty:
            out["uncertainty"] = jsonable([b.to_dict() for b in self.uncertainty])
        if self.dynamic is not None:
            dy = self.dynamic
            out["dynamic_fit"] = {
                "method": dy.method,
                "frequency_method": dy.frequency_method,
                "fit_frequencies_Hz": [float(f) for f in dy.fit_frequencies_Hz],
                "weights": jsonable(dy.weights[0] if dy.weights[0] != "custom" else dy.weights),
                "curvature_fitted": dy.curvature_fitted,
                "cost_eq22": dy.cost,
                "step_cost": dy.step_cost,
                "frequency_cost": dy.frequency_cost,
                "evaluations": dy.n_evaluations,
                "jacobians": dy.n_jacobians,
                "rejected_trials": dy.rejected_trials,
                "statistics": dy.statistics.as_dict() if dy.statistics else None,
                "initial_guess": jsonable({k: v for k, v in dy.initial.items()}),
            }
        return out
