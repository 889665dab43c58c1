"""Static equilibria (eq. 20): residual, analytic limit, flat membrane, no-equilibrium errors."""
import numpy as np
import pytest

from dea_ros.model import DEAModel, NoEquilibriumError, preset, static_equilibrium


@pytest.mark.parametrize("name", ["LP1", "A1", "A2"])
def test_force_balance_residual(name):
    p = preset(name)
    u = np.linspace(0, 2500, 11)
    eq = static_equilibrium(p, u)
    model = DEAModel.from_parameters(p)
    force = model.static_force_N(eq.displacement_m, u**2)
    np.testing.assert_allclose(force, p.mass_kg * 9.81, rtol=1e-12)
    assert np.all(eq.stiffness_N_per_m > 0)
    assert np.all(np.diff(eq.displacement_m) > 0)  # the Maxwell pressure lowers the mass


def test_small_mass_limit_is_linear_spring():
    """For a tiny mass d -> m g / (c1bar sigma_h(1)) (eq. 20 with s -> 1)."""
    p = preset("A2").replace(mass_kg=1e-6)
    d = static_equilibrium(p, 0.0).displacement_m
    assert d == pytest.approx(1e-6 * 9.81 / (p.c1bar_m * p.prestress_Pa), rel=1e-5)


def test_flat_membrane_without_mass():
    p = preset("A2")
    eq = static_equilibrium(p, [0.0, 2500.0], mass_kg=0.0)
    np.testing.assert_array_equal(eq.displacement_m, [0.0, 0.0])
    assert np.all(eq.stiffness_N_per_m > 0.0)  # the tensioned flat membrane is stable


def test_scalar_and_vector_shapes():
    p = preset("LP1")
    assert isinstance(static_equilibrium(p, 2000.0).displacement_m, float)
    assert static_equilibrium(p, np.zeros((2, 3))).displacement_m.shape == (2, 3)
    assert static_equilibrium(p, 0.0).state.shape == (3,)


def test_no_equilibrium_is_reported_not_invented():
    p = preset("A2").replace(mass_kg=5.0)  # far more than the membrane carries
    with pytest.raises(NoEquilibriumError, match="no static equilibrium"):
        static_equilibrium(p, 0.0)


def test_bad_inputs():
    p = preset("A2")
    with pytest.raises(ValueError, match="voltage_V"):
        static_equilibrium(p, float("nan"))
    with pytest.raises(ValueError, match="mass_kg"):
        static_equilibrium(p, 0.0, mass_kg=-1.0)
