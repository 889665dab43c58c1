"""A frequency point of eq. 24 and the model there: its periodic solution and the exact gradient of d_rms.

A :class:`FrequencyPoint` is one measured RMS value (eq. 21) with its excitation (the nominal sine or
the applied waveform) and the response it is fitted with: the T/2 orbit ("periodic") or a
period-doubled one. :func:`point_solution` computes that harmonic-balance solution;
:func:`periodic_rms_gradient` its d_rms and the exact gradient w.r.t. the parameters (implicit
function theorem on the collocation equations). The dynamic fit, the joint refinement and the
evaluation share them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.dynamics import DEAModel
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..errors import HarmonicBalanceError
from ..solvers.collocation import CollocationSystem
from ..solvers.newton import solve_native
from ..solvers.periodic_solution import PeriodicSolution
from ..solvers.inputs import SinePeriodic
from ..solvers.transient import rhs_log_parameter_derivative, rhs_permittivity_derivative, rhs_stress_derivative

__all__ = ["FrequencyPoint", "point_solution", "periodic_rms_gradient", "rms_reference_m"]


@dataclass(frozen=True)
class FrequencyPoint:
    """One frequency of eq. 24: excitation and the measured RMS (eq. 21)."""

    frequency_Hz: float
    amplitude_V: float
    measured_rms_m: float
    mass_kg: float
    source: str
    measured_std_m: float | None = None
    periodic_input: object = None  # the applied waveform (SineData.inputs); None: the nominal sine
    #: the response the record shows and is fitted with: "periodic" (period of u^2, T/2) or
    #: "period-doubled" (period T; the full-period harmonic balance on the period-doubled branch)
    kind: str = "periodic"
    guess: object = None           # a collocation state on the matching branch (seeds harmonic balance)
    #: the measured rest position d0 (m) the record's RMS is about (eq. 21; SineData.d0_m). The model's RMS
    #: is then taken about the same measured value, so its measurement error, common to every record
    #: measured from that rest, cancels instead of entering every RMS residual; None: about the model's
    #: own rest position at 0 V
    rest_d0_m: float | None = None

    @property
    def excitation(self):
        """The periodic input of eq. 24 (the applied waveform, or the nominal sine)."""
        return self.periodic_input or SinePeriodic(self.amplitude_V, self.frequency_Hz)


def rms_reference_m(params: MembraneParameters, point: FrequencyPoint) -> float:
    """The rest position d0 (m) a point's RMS is taken about (eq. 21): the measured one the record states
    (``rest_d0_m``), else the model's at 0 V with the record's mass."""
    if point.rest_d0_m is not None:
        return float(point.rest_d0_m)
    p = params if point.mass_kg == params.mass_kg else params.replace(mass_kg=point.mass_kg)
    return float(static_equilibrium(p, 0.0).displacement_m)


def point_solution(params: MembraneParameters, point: FrequencyPoint, n_harmonics: int,
                   guess=None) -> PeriodicSolution:
    """The harmonic-balance solution a frequency point is fitted with (its ``kind``).

    ``periodic``: N harmonics of 2f (period T/2), seeded from ``guess`` or the point's branch
    state (so a coexisting branch is kept). ``period-doubled``: 2N harmonics of f on the full
    period (the same spectral reach), seeded from a state of the period-doubled branch; a solve
    that falls back onto the symmetric orbit raises :class:`HarmonicBalanceError`.
    """
    seed = guess if guess is not None else point.guess
    if point.kind == "period-doubled":
        if seed is None:
            raise HarmonicBalanceError(f"{point.frequency_Hz:g} Hz: no period-doubled orbit to start from")
        sol = solve_native(params, point.excitation, 2 * n_harmonics, x_guess=seed, use_symmetry=False,
                           stability=False)
        if sol.odd_harmonic_ratio() < 1e-3:
            raise HarmonicBalanceError(f"{point.frequency_Hz:g} Hz: the period-doubled orbit vanished "
                                       "(these parameters have no period doubling there)")
        return sol
    try:
        return solve_native(params, point.excitation, n_harmonics, x_guess=seed, stability=False)
    except HarmonicBalanceError:
        pass
    try:
        return solve_native(params, point.excitation, n_harmonics, stability=False)  # cold (homotopy)
    except HarmonicBalanceError:
        # near a fold the Jacobian is ill-conditioned: the residual reaches the floating-point floor
        # (1e-14) while the Newton step stays above 1e-10; a step below 1e-8 (scaled) is still far
        # more accurate than any RMS value measured
        return solve_native(params, point.excitation, n_harmonics, x_guess=seed, tol=1e-8, stability=False)


def periodic_rms_gradient(params: MembraneParameters, sol: PeriodicSolution, d0: float, dd0=None,
                          directions=None, permittivity: bool = False) -> tuple[float, np.ndarray]:
    """d_rms (eq. 21) of a harmonic-balance solution and its exact gradient.

    Gradient w.r.t. (ln k1, ln eta1, ln eta2), then the coefficients c_j of ``directions`` (q, 6)
    in (beta, gamma), then eps_r when ``permittivity``; by the implicit function theorem on the
    collocation equations, dX/dtheta = -J^-1 dR/dtheta. ``dd0`` (one value per direction and
    eps_r): the derivative of the reference d0 (the rest position moves with the stress).
    Works for any response period (T/2 or the full period of a period-doubled orbit).
    """
    model = DEAModel.from_parameters(params)
    m = sol.n_points
    divisor = sol.period_divisor
    omega = sol.periodic_input.omega * divisor
    phases = 2.0 * np.pi * np.arange(m) / m
    u2 = sol.periodic_input.at_phase(phases / divisor) ** 2
    x = sol.state
    d_ref = max(float(np.max(np.abs(x[0]))), 1e-6)
    scale = np.array([d_ref, max(float(np.max(np.abs(x[1]))), 1e-9), d_ref * omega])
    system = CollocationSystem(model, m, scale, omega)
    _r, jac = system.residual_and_jacobian(system.to_z(x), omega, u2)
    g = rhs_log_parameter_derivative(model, x)                     # (3 params, 3, M)
    if directions is not None:
        g = np.concatenate([g, rhs_stress_derivative(model, x, directions)], axis=0)
    if permittivity:
        g = np.concatenate([g, rhs_permittivity_derivative(model, x, u2)], axis=0)
    n_par = g.shape[0]
    dr = -(g / (scale * omega)[None, :, None]).reshape(n_par, 3 * m)  # scaled dR/dtheta
    dz = np.linalg.solve(jac, -dr.T)                                 # (3M, P)
    dd = dz[:m] * scale[0]                                           # d(d_k)/dtheta, (M, P)
    dev = x[0] - d0
    rms = float(np.sqrt(np.mean(dev**2)))
    if dd0 is not None and n_par > 3:
        dd = dd.copy()
        extra = np.asarray(dd0, float).reshape(-1)
        dd[:, 3:3 + extra.size] -= extra[None, :]                    # d0 moves with the stress
    grad = (dev @ dd) / (m * rms) if rms > 0 else np.zeros(n_par)
    return rms, grad
