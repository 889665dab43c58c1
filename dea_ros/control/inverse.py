"""Model inversion: the input u^2 that produces a displacement, statically and dynamically.

Static inverse (eq. 20 solved for u^2). At rest (d' = d'' = 0, eps1 relaxed so sigma_v1 = 0,
eq. 11) the force balance on the mass is ``m g = c1bar d/s(d) (sigma_h(s) + c2 s u^2)``; it is
linear in u^2, so the voltage whose equilibrium is d has the closed form::

    u^2 = (m g s / (c1bar d) - sigma_h(s)) / (c2 s)

Reachable range: the membrane only pulls the mass down by expanding under the Maxwell pressure
(u^2 >= 0), so the static displacements reachable with 0 <= u <= u_max are
[d(0 V), d(u_max)] (the stable branch of :func:`dea_ros.model.static_equilibrium`).

Dynamic inverse (eq. 5 / eq. 18 solved for u^2). For a reference d_r(t) with velocity v_r and
acceleration a_r, the third row of eq. 18 is affine in u^2::

    a_r = g - (c1bar/m) d/s (c2 s u^2 + sigma_h(s) + k1 (lambda_r - 1 - eps1) + eta2 phi(d) v_r)

    u^2 = ((g - a_r) s m / (c1bar d) - sigma_h(s) - k1 (lambda_r - 1 - eps1) - eta2 phi v_r) / (c2 s)

with the viscoelastic strain eps1 integrated alongside the reference (eq. 11,
``eps1' = k1/eta1 (lambda_r(d_r) - 1 - eps1)``, :class:`StrainIntegrator`). Since the model has
relative degree 2 from u^2 to d, applying this u^2(t) to the model from the reference's initial
state reproduces d_r(t) exactly (up to the integrator's tolerance); eps1 is the model's zero
dynamics, stable because k1/eta1 > 0.

The input gain of the linearised model is ``b(d) = d(d'')/d(u^2) = -(c1bar/m) c2 d > 0``
(eqs. 6, 18): the feedback acts on u^2 through it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from ..model import DEAModel, MembraneParameters, NoEquilibriumError, static_equilibrium
from ..errors import UnreachableReferenceError

__all__ = ["UnreachableReferenceError", "ModelInverse", "StrainIntegrator"]


def _um(x_m: float) -> str:
    return f"{x_m * 1e6:.1f} um"


@dataclass(frozen=True)
class _Range:
    low_m: float
    high_m: float


class ModelInverse:
    """Static (eq. 20) and dynamic (eq. 5) inverse of one identified membrane with its mass.

    ``max_voltage_V`` is the highest voltage the controller may use (at most the amplifier's
    limit); the reachable static range is [d(0 V), d(max_voltage_V)]. If the membrane has no
    stable equilibrium up to ``max_voltage_V`` (electromechanical instability: the static
    stiffness falls to zero), the usable top voltage is lowered to the last voltage with a
    stiffness of at least ``min_stiffness_fraction`` of the stiffness at 0 V, and
    :attr:`top_voltage_V` says so.
    """

    def __init__(self, params: MembraneParameters, max_voltage_V: float, min_stiffness_fraction: float = 0.2):
        if not (math.isfinite(max_voltage_V) and max_voltage_V > 0.0):
            raise ValueError(f"max_voltage_V: must be a positive number of volts, got {max_voltage_V!r}")
        self.params = params
        self.model = DEAModel.from_parameters(params)   # raises for mass_kg <= 0
        self.max_voltage_V = float(max_voltage_V)
        self._mg = params.mass_kg * params.gravity_m_per_s2
        self._c1bar = params.c1bar_m
        try:
            eq0 = static_equilibrium(params, 0.0)
        except NoEquilibriumError as exc:
            raise ValueError(f"membrane {params.name}: {exc}") from None
        if not eq0.stiffness_N_per_m > 0.0:
            raise ValueError(
                f"membrane {params.name}: no stable static equilibrium at 0 V with mass {params.mass_kg} kg; "
                "check the parameters file (mass_kg, beta_Pa, gamma_Pa)"
            )
        self.d_min_m = float(eq0.displacement_m)
        # Walk up the stable branch with the closed-form u^2(d): it ends where u reaches the limit,
        # or where the static stiffness falls below min_stiffness_fraction of its 0 V value (the
        # fold of the electromechanical instability is where it reaches 0).
        l0 = params.electrode_width_m
        d = self.d_min_m + (l0 - self.d_min_m) * np.linspace(0.0, 1.0, 4001) ** 2
        u2 = self.static_u2(d)
        stiff = self.model.static_stiffness_N_per_m(d, np.maximum(u2, 0.0))
        bad = (stiff < min_stiffness_fraction * float(eq0.stiffness_N_per_m)) | (u2 >= self.max_voltage_V ** 2)
        bad[0] = False
        k = int(np.argmax(bad)) if bad.any() else d.size - 1
        lo, hi = float(d[k - 1]), float(d[k])
        for _ in range(60):                  # bisection on the same criterion
            mid = 0.5 * (lo + hi)
            u2m = float(self.static_u2(mid))
            if u2m >= self.max_voltage_V ** 2 or self.model.static_stiffness_N_per_m(mid, max(u2m, 0.0)) < \
                    min_stiffness_fraction * float(eq0.stiffness_N_per_m):
                hi = mid
            else:
                lo = mid
        self.d_max_m = lo
        self.top_voltage_V = min(math.sqrt(max(float(self.static_u2(lo)), 0.0)), self.max_voltage_V)

    # ------------------------------------------------------------------ static
    @property
    def reachable_range_m(self) -> tuple[float, float]:
        """(d(0 V), d(top voltage)) in m: the displacements the controller can hold at rest."""
        return self.d_min_m, self.d_max_m

    def check_reachable(self, displacement_m: float, what: str = "setpoint") -> None:
        """Raise :class:`UnreachableReferenceError` for a displacement outside the reachable range."""
        d = float(displacement_m)
        lo, hi = self.reachable_range_m
        if not math.isfinite(d):
            raise UnreachableReferenceError(f"{what}: must be a finite displacement in m, got {displacement_m!r}")
        if d < lo - 1e-12 or d > hi + 1e-12:
            side = ("above d(0 V): the actuator can only pull the mass down (u^2 >= 0)" if d < lo
                    else f"below d({self.top_voltage_V:.0f} V), the largest voltage allowed")
            raise UnreachableReferenceError(
                f"{what} {_um(d)} is outside the reachable range [{_um(lo)}, {_um(hi)}] "
                f"(+ downwards from the flat membrane) of membrane {self.params.name} with "
                f"{self.params.mass_kg * 1e3:g} g: it is {side}; choose a displacement in the range (in m)"
            )

    def static_u2(self, displacement_m):
        """u^2 (V^2) whose static equilibrium is d (eq. 20), any d > 0; may be < 0 outside the range."""
        d = np.asarray(displacement_m, dtype=float)
        m = self.model
        s = m.stretch_squared(d)
        out = (self._mg * s / (self._c1bar * d) - m.hyperelastic_stress(s)) / (m.c2 * s)
        return float(out) if out.ndim == 0 else out

    def static_displacement(self, u2_V2: float) -> float:
        """The displacement (m) in the reachable range whose static u^2 (eq. 20) is ``u2_V2`` (bisection;
        u^2 rises with d along the stable branch); clamped to the range's ends."""
        lo, hi = self.reachable_range_m
        target = float(u2_V2)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if float(self.static_u2(mid)) < target:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def static_voltage(self, displacement_m, check: bool = True):
        """The voltage (V) whose static equilibrium is d (eq. 20); checks the reachable range."""
        d = np.asarray(displacement_m, dtype=float)
        if check:
            for x in np.atleast_1d(d):
                self.check_reachable(float(x), "displacement")
        u = np.sqrt(np.maximum(self.static_u2(d), 0.0))
        return float(u) if np.ndim(u) == 0 else u

    # ----------------------------------------------------------------- dynamic
    def input_gain(self, displacement_m):
        """b(d) = d(d'')/d(u^2) = -(c1bar/m) c2 d, m/s^2 per V^2 (> 0 for d > 0)."""
        return self.model.input_gain_u2(displacement_m)

    def dynamic_u2(self, d, v, a, eps1):
        """u^2 (V^2) for which the model has acceleration a at state (d, eps1, v) (eq. 5 inverted).

        Unclamped: a negative value means the motion needs the membrane to push the mass up,
        which it cannot do.
        """
        m = self.model
        s = 1.0 + d * d / m.l0_sq
        lam = s ** 0.5
        phi = d / (m.l0_sq * lam)                                    # eq. 12
        required = (m.g - a) * s / (m.force_gain * d)                # total stress for acceleration a
        rest = m.hyperelastic_stress(s) + m.k1 * (lam - 1.0 - eps1) + m.eta2 * phi * v
        return (required - rest) / (m.c2 * s)

    def relaxed_strain(self, displacement_m):
        """eps1 of the relaxed membrane at d: lambda_r(d) - 1 (eq. 11 at rest)."""
        if type(displacement_m) is float:   # the control loop's scalar path, without numpy's overhead
            return math.sqrt(1.0 + displacement_m * displacement_m / self.model.l0_sq) - 1.0
        d = np.asarray(displacement_m, dtype=float)
        out = np.sqrt(1.0 + d * d / self.model.l0_sq) - 1.0
        return float(out) if out.ndim == 0 else out

    def linearisation(self, displacement_m: float, eps1: float | None = None, voltage_V: float | None = None):
        """(k, c, b): stiffness/m (1/s^2), damping/m (1/s) and input gain b (m/s^2/V^2) at rest at d.

        Linearised eq. 18 with eps1 frozen (the fast mechanical mode):
        ``dd'' = -k dd - c dd' + b du^2``. Defaults: eps1 relaxed, u^2 the static inverse.
        """
        d = float(displacement_m)
        e = self.relaxed_strain(d) if eps1 is None else float(eps1)
        u2 = self.static_u2(d) if voltage_V is None else float(voltage_V) ** 2
        jac = self.model.jacobian_u2(d, e, 0.0, u2)
        return -float(jac[2][0]), -float(jac[2][2]), float(self.input_gain(d))


class StrainIntegrator:
    """eps1 along a displacement signal (eq. 11), exact for a piecewise-linear lambda_r - 1.

    ``step(d_next, dt)`` advances eps1 from the previous displacement to ``d_next`` over ``dt``
    with the exponential integrator of ``eps1' = r (lambda_r(d) - 1 - eps1)`` (r = k1/eta1),
    the forcing interpolated linearly in time (second-order accurate for any dt).
    """

    def __init__(self, inverse: ModelInverse, displacement_m: float, eps1: float | None = None):
        self.inverse = inverse
        self.rate = inverse.model.relax_rate
        self.d = float(displacement_m)
        self.eps1 = inverse.relaxed_strain(self.d) if eps1 is None else float(eps1)
        self._f, self._f_at = math.nan, math.nan   # cache of relaxed_strain(self.d)

    def reset(self, displacement_m: float, eps1: float | None = None) -> None:
        self.d = float(displacement_m)
        self.eps1 = self.inverse.relaxed_strain(self.d) if eps1 is None else float(eps1)

    def step(self, displacement_m: float, dt_s: float) -> float:
        if dt_s <= 0.0:
            self.d = float(displacement_m)
            return self.eps1
        if self._f_at != self.d:                 # lambda_r - 1 at the previous displacement (cached)
            self._f, self._f_at = self.inverse.relaxed_strain(self.d), self.d
        f0 = self._f
        f1 = self.inverse.relaxed_strain(float(displacement_m))
        x = self.rate * dt_s
        ex = math.exp(-x)
        # exact solution of e' = r (f0 + (f1 - f0) t/dt - e) over [0, dt]
        slope = (f1 - f0) / x if x > 1e-12 else 0.0
        self.eps1 = f1 - slope + (self.eps1 - f0 + slope) * ex
        self.d = float(displacement_m)
        self._f, self._f_at = f1, self.d
        return self.eps1

    def run(self, displacements_m, dt_s: float) -> np.ndarray:
        """eps1 along displacements on a uniform grid of step ``dt_s``, from the current state.

        The first displacement is taken as the current one (eps1[0] = the current eps1); the same
        exact exponential step as :meth:`step`, written as the linear recursion
        ``e_k = exp(-r dt) e_(k-1) + b_k`` and evaluated by one ``lfilter`` call (the planner's
        checks are vectorised with it). Leaves the integrator at the last displacement.
        """
        d = np.asarray(displacements_m, dtype=float)
        f = self.inverse.relaxed_strain(d)
        x = self.rate * float(dt_s)
        if d.size < 2 or x <= 0.0:
            out = np.full(d.size, self.eps1)
        else:
            ex = math.exp(-x)
            slope = np.diff(f) / x if x > 1e-12 else np.zeros(d.size - 1)
            b = f[1:] - slope + (slope - f[:-1]) * ex
            rest, _ = lfilter([1.0], [1.0, -ex], b, zi=[ex * self.eps1])
            out = np.concatenate(([self.eps1], rest))
        self.eps1 = float(out[-1])
        self.d = float(d[-1]) if d.size else self.d
        return out
