"""Forward integration of the DEA model: adaptive (offline) and fixed-step (real time).

* :func:`simulate` integrates any :class:`~dea_ros.solvers.inputs.VoltageSignal`
  with SciPy's adaptive integrators and the analytic Jacobian, restarting at the
  signal's breakpoints (steps), from the static equilibrium by default.
* :func:`simulate_held` integrates the voltages an amplifier holds for one update period each
  (zero-order hold) with the compiled embedded Dormand-Prince 5(4) pair, every hold on its own
  (:mod:`.integrate_kernels`): the rig's applied voltage, fast over long experiments.
* :class:`RealTimeStepper` advances the state by a fixed step with classical
  RK4 on plain floats (no numpy in the loop), for the model node at 1 kHz and
  faster. The input is held constant over a step (zero-order hold, as a DAQ does).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from ..model.dynamics import DEAModel
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from .inputs import ConstantVoltage, VoltageSignal, check_voltage
from ..errors import IntegrationError
from .integrate_kernels import held_trajectory

__all__ = ["TimeResponse", "simulate", "simulate_held", "RealTimeStepper", "state_scale", "IntegrationError"]


def state_scale(params: MembraneParameters) -> np.ndarray:
    """Typical magnitudes of [d (m), eps1 (-), d' (m/s)] used for tolerances and scaling."""
    d_ref = max(float(static_equilibrium(params, 0.0).displacement_m), 0.05 * params.electrode_width_m) \
        if params.mass_kg > 0 else 0.05 * params.electrode_width_m
    eps_ref = max((d_ref / params.electrode_width_m) ** 2, 1e-6)
    v_ref = d_ref * 2 * np.pi * 20.0
    return np.array([d_ref, eps_ref, v_ref])


@dataclass
class TimeResponse:
    """Sampled trajectory: time (s), state (3, K), voltage (V)."""

    time_s: np.ndarray
    state: np.ndarray
    voltage_V: np.ndarray
    wall_time_s: float = 0.0
    rhs_evaluations: int = 0

    @property
    def displacement_m(self) -> np.ndarray:
        return self.state[0]

    @property
    def viscoelastic_strain(self) -> np.ndarray:
        return self.state[1]

    @property
    def velocity_m_per_s(self) -> np.ndarray:
        return self.state[2]


def initial_state(params: MembraneParameters, voltage_V: float) -> np.ndarray:
    """Static equilibrium state [d, eps1, 0] at a constant voltage."""
    eq = static_equilibrium(params, float(voltage_V))
    return np.asarray(eq.state, dtype=float).reshape(3)


def simulate(
    params: MembraneParameters,
    signal: VoltageSignal | float,
    t_end_s: float,
    sample_rate_Hz: float | None = 1000.0,
    t_eval=None,
    x0=None,
    method: str = "DOP853",
    rtol: float = 1e-8,
    atol_scale: float = 1e-8,
    t_start_s: float = 0.0,
) -> TimeResponse:
    """Integrate the model (eq. 17) under a voltage signal from t_start_s to t_end_s.

    ``x0`` defaults to the static equilibrium at u(t_start). Output at
    ``t_eval`` if given, else at ``sample_rate_Hz``. ``method`` is any
    :func:`scipy.integrate.solve_ivp` method; implicit ones use the analytic
    Jacobian. Absolute tolerances are ``atol_scale`` times the state scale.
    """
    if not isinstance(signal, VoltageSignal):
        signal = ConstantVoltage(float(check_voltage(signal)))
    if not (np.isfinite(t_end_s) and t_end_s > t_start_s):
        raise ValueError(f"t_end_s: must be > t_start_s ({t_start_s}), got {t_end_s}")
    model = DEAModel.from_parameters(params)
    if t_eval is None:
        if not sample_rate_Hz or sample_rate_Hz <= 0:
            raise ValueError("sample_rate_Hz: must be > 0 when t_eval is not given")
        n = int(np.floor((t_end_s - t_start_s) * sample_rate_Hz + 1e-9)) + 1
        t_eval = t_start_s + np.arange(n) / sample_rate_Hz
    t_eval = np.asarray(t_eval, dtype=float)
    x = initial_state(params, float(signal(t_start_s))) if x0 is None else np.asarray(x0, float).copy()
    if x.shape != (3,) or not np.all(np.isfinite(x)):
        raise ValueError(f"x0: must be 3 finite numbers [d, eps1, d'], got {x0!r}")
    atol = atol_scale * state_scale(params)

    def fun(t, y):
        return model.rhs(y, signal(t))

    def jac(t, y):
        return model.jacobian(y, signal(t))

    cuts = [t_start_s] + sorted(b for b in signal.breakpoints if t_start_s < b < t_end_s) + [t_end_s]
    out = np.empty((3, t_eval.size))
    filled = np.zeros(t_eval.size, dtype=bool)
    nfev = 0
    t0 = time.perf_counter()
    for a, b in zip(cuts[:-1], cuts[1:]):
        last = b == cuts[-1]
        mask = (t_eval >= a) & ((t_eval <= b) if last else (t_eval < b)) & ~filled
        kwargs = {"jac": jac} if method in ("Radau", "BDF", "LSODA") else {}
        sol = solve_ivp(
            fun, (a, b), x, method=method, rtol=rtol, atol=atol, dense_output=True, **kwargs
        )
        if not sol.success:
            raise IntegrationError(f"integration failed on [{a}, {b}] s: {sol.message}")
        nfev += sol.nfev
        if mask.any():
            out[:, mask] = sol.sol(t_eval[mask])
            filled |= mask
        x = sol.y[:, -1]
    wall = time.perf_counter() - t0
    return TimeResponse(t_eval, out, np.asarray(signal(t_eval), float), wall, nfev)


def simulate_held(params: MembraneParameters, voltages_V, update_period_s: float, x0=None, rtol: float = 1e-10,
                  atol_scale: float = 1e-10) -> TimeResponse:
    """The model under voltages held for one update period each: ``voltages_V[k]`` from k to k + 1 periods.

    Returns the states at the update instants 0, T, ..., nT (n + 1 of them; the voltage column is the value
    held from each instant on, 0 V after the last). ``x0`` defaults to the rest (static equilibrium) at the
    first voltage. Adaptive embedded Dormand-Prince 5(4) on each hold (:mod:`.integrate_kernels`), relative
    tolerance ``rtol``, absolute ``atol_scale`` times the state scale (:func:`state_scale`).
    """
    u = check_voltage(np.asarray(voltages_V, float).reshape(-1), "voltages_V")
    if not (np.isfinite(update_period_s) and update_period_s > 0):
        raise ValueError(f"update_period_s: must be > 0, got {update_period_s}")
    x = initial_state(params, float(u[0]) if u.size else 0.0) if x0 is None else np.asarray(x0, float).copy()
    if x.shape != (3,) or not np.all(np.isfinite(x)):
        raise ValueError(f"x0: must be 3 finite numbers [d, eps1, d'], got {x0!r}")
    t0 = time.perf_counter()
    constants = tuple(float(c) for c in DEAModel.from_parameters(params).constants)
    states, accepted, rejected, failed = held_trajectory(constants, x, u * u, float(update_period_s), float(rtol),
                                                         atol_scale * state_scale(params))
    if failed >= 0:
        raise IntegrationError(f"held-voltage integration failed in hold {failed} "
                               f"({failed * update_period_s:.4f} s, {u[failed]:.1f} V): step size collapsed")
    times = np.arange(u.size + 1) * float(update_period_s)
    return TimeResponse(times, states, np.r_[u, 0.0], time.perf_counter() - t0, 7 * (accepted + rejected))


class RealTimeStepper:
    """Fixed-step RK4 for real-time prediction (the model node).

    ``step(voltage_V, dt_s)`` advances by ``dt_s`` with ``substeps`` RK4 steps
    of the voltage held constant and returns the displacement (m). Pure-Python
    float arithmetic: about 20-40 us per RK4 step on a lab PC.
    """

    def __init__(self, params: MembraneParameters, dt_s: float = 1e-3, substeps: int = 1,
                 initial_voltage_V: float = 0.0):
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s: must be > 0, got {dt_s}")
        if int(substeps) < 1:
            raise ValueError(f"substeps: must be >= 1, got {substeps}")
        self.params = params
        self.model = DEAModel.from_parameters(params)
        self.dt_s = float(dt_s)
        self.substeps = int(substeps)
        self.reset(initial_voltage_V)

    def reset(self, voltage_V: float = 0.0) -> None:
        """Back to the static equilibrium at a constant voltage."""
        d, e, v = initial_state(self.params, float(check_voltage(voltage_V)))
        self.state = [float(d), float(e), float(v)]

    @property
    def displacement_m(self) -> float:
        return self.state[0]

    def step(self, voltage_V: float, dt_s: float | None = None) -> float:
        """Advance by dt_s (default: the constructor's) holding the voltage; return d in m."""
        h = (self.dt_s if dt_s is None else float(dt_s)) / self.substeps
        u2 = float(voltage_V) ** 2
        f = self.model.rhs_u2
        d, e, v = self.state
        for _ in range(self.substeps):
            k1 = f(d, e, v, u2)
            k2 = f(d + 0.5 * h * k1[0], e + 0.5 * h * k1[1], v + 0.5 * h * k1[2], u2)
            k3 = f(d + 0.5 * h * k2[0], e + 0.5 * h * k2[1], v + 0.5 * h * k2[2], u2)
            k4 = f(d + h * k3[0], e + h * k3[1], v + h * k3[2], u2)
            c = h / 6.0
            d += c * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0])
            e += c * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])
            v += c * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2])
        if not (d == d and abs(d) < 1.0):  # NaN or a blow-up: keep the last good state
            raise FloatingPointError(
                f"real-time stepper diverged (d = {d}); reduce dt_s or raise substeps"
            )
        self.state = [d, e, v]
        return d

    def run(self, voltages_V) -> np.ndarray:
        """Step through a sequence of voltages (one per dt_s); return the displacements."""
        return np.array([self.step(u) for u in np.asarray(voltages_V, float)])
