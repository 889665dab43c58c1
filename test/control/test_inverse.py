"""Static inverse (eq. 20) and dynamic inverse (eq. 5): against the forward solvers, not against itself."""
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from dea_ros.control import ModelInverse, StrainIntegrator, UnreachableReferenceError
from dea_ros.model import DEAModel, preset, static_equilibrium
from dea_ros.solvers import SineVoltage, simulate


@pytest.mark.parametrize("name", ["LP1", "A2", "unlike"])
def test_static_inverse_round_trips_through_the_forward_equilibrium(name, unlike):
    p = unlike if name == "unlike" else preset(name)
    umax = 0.9 * p.breakdown_voltage_V()
    inv = ModelInverse(p, umax)
    lo, hi = inv.reachable_range_m
    # the range is the forward solver's d(0 V) and d(max V)
    assert lo == pytest.approx(static_equilibrium(p, 0.0).displacement_m, rel=1e-12)
    assert hi == pytest.approx(static_equilibrium(p, inv.top_voltage_V).displacement_m, rel=1e-12)
    assert hi - lo > 50e-6
    d = np.linspace(lo, hi, 9)
    u = inv.static_voltage(d)
    assert u[0] == pytest.approx(0.0, abs=1e-3 * umax) and u[-1] == pytest.approx(inv.top_voltage_V, rel=1e-6)
    assert np.all(np.diff(u) > 0)
    back = static_equilibrium(p, u).displacement_m       # bisection + Newton on the force balance
    np.testing.assert_allclose(back, d, atol=1e-10)


def test_unreachable_displacements_are_refused_with_the_range(unlike):
    inv = ModelInverse(unlike, 2000.0)
    lo, hi = inv.reachable_range_m
    with pytest.raises(UnreachableReferenceError, match=r"reachable range.*push|pull the mass down"):
        inv.static_voltage(lo - 10e-6)
    with pytest.raises(UnreachableReferenceError, match=r"below d\(2000 V\)"):
        inv.static_voltage(hi + 10e-6)
    with pytest.raises(UnreachableReferenceError, match="finite"):
        inv.check_reachable(float("nan"))
    # a lower voltage limit shrinks the range from the top only
    inv2 = ModelInverse(unlike, 1000.0)
    assert inv2.reachable_range_m[0] == pytest.approx(lo) and inv2.reachable_range_m[1] < hi


def test_top_voltage_stops_before_the_electromechanical_instability():
    p = preset("LP1").replace(relative_permittivity=9.0)   # the membrane buckles well below 3.4 kV
    inv = ModelInverse(p, 0.9 * p.breakdown_voltage_V())
    assert inv.top_voltage_V < inv.max_voltage_V
    eq = static_equilibrium(p, inv.top_voltage_V)
    assert eq.stiffness_N_per_m > 0.0


def _model_trajectory(p, t_end=1.5):
    """A model trajectory: forward integration under a smooth voltage (offset sine, 7 Hz)."""
    sig = SineVoltage(amplitude_V=700.0, frequency_Hz=7.0, offset_V=1500.0)
    t = np.linspace(0.0, t_end, 1501)
    with np.errstate(over="ignore", invalid="ignore"):   # DOP853 may try (and reject) a huge first step
        res = simulate(p, sig, t_end, t_eval=t, rtol=1e-11, atol_scale=1e-11)
    return res, sig


@pytest.mark.parametrize("name", ["A2", "unlike"])
def test_dynamic_inverse_recovers_the_input_of_a_model_trajectory(name, unlike):
    """Feed d, d', d'' and eps1 of a forward-integrated trajectory to the inverse: u^2 comes back."""
    p = unlike if name == "unlike" else preset(name)
    res, sig = _model_trajectory(p)
    inv = ModelInverse(p, 3000.0)
    model = DEAModel.from_parameters(p)
    d, e, v = res.state
    acc = model.rhs(res.state, res.voltage_V)[2]
    u2 = inv.dynamic_u2(d, v, acc, e)
    np.testing.assert_allclose(u2, res.voltage_V ** 2, rtol=1e-9, atol=1e-6)
    # and with eps1 from the strain integrator run along d only (eq. 11 integrated alongside)
    strain = StrainIntegrator(inv, d[0], e[0])
    eps = [strain.eps1] + [strain.step(x, 1e-3) for x in d[1:]]
    u2b = inv.dynamic_u2(d, v, acc, np.array(eps))
    assert np.max(np.abs(np.sqrt(np.maximum(u2b, 0)) - res.voltage_V)) < 0.5   # V, from 0.8-2.2 kV


def test_strain_integrator_matches_converged_integration(unlike):
    inv = ModelInverse(unlike, 2000.0)
    lo, hi = inv.reachable_range_m

    def d_of_t(t):
        return lo + (hi - lo) * (0.5 + 0.4 * np.sin(2 * np.pi * 3.0 * t))

    r = inv.model.relax_rate
    sol = solve_ivp(lambda t, y: r * (inv.relaxed_strain(d_of_t(t)) - y), (0, 1.0), [inv.relaxed_strain(d_of_t(0))],
                    rtol=1e-12, atol=1e-15, dense_output=True)
    strain = StrainIntegrator(inv, d_of_t(0.0))
    ts = np.arange(1, 1001) * 1e-3
    got = np.array([strain.step(d_of_t(t), 1e-3) for t in ts])
    ref = sol.sol(ts)[0]
    assert np.max(np.abs(got - ref)) < 1e-3 * np.ptp(ref)


def test_strain_integrator_run_is_the_step_over_a_grid(unlike):
    """The planner's vectorised run() and the loop's per-sample step() are the same exponential step."""
    inv = ModelInverse(unlike, 2000.0)
    lo, hi = inv.reachable_range_m
    d = lo + (hi - lo) * (0.5 + 0.4 * np.sin(2 * np.pi * 3.0 * np.arange(400) * 1e-3))
    one = StrainIntegrator(inv, d[0], 0.01)
    stepped = [one.eps1] + [one.step(x, 1e-3) for x in d[1:]]
    other = StrainIntegrator(inv, d[0], 0.01)
    ran = other.run(d, 1e-3)
    np.testing.assert_allclose(ran, stepped, rtol=1e-12, atol=1e-15)
    assert other.eps1 == pytest.approx(one.eps1, rel=1e-12) and other.d == one.d
