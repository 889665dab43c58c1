"""Dynamics: vectorised rhs, analytic Jacobian vs finite differences, physical limits."""
import numpy as np
import pytest

from dea_ros.model import DEAModel, preset, static_equilibrium


@pytest.fixture(params=["LP1", "A1", "A2"])
def model(request):
    return DEAModel.from_parameters(preset(request.param))


def random_states(rng, n):
    d = rng.uniform(2e-4, 2e-3, n)
    eps = rng.uniform(0.0, 5e-3, n)
    v = rng.uniform(-0.2, 0.2, n)
    return np.stack([d, eps, v])


def test_jacobian_matches_central_differences(model):
    rng = np.random.default_rng(1)
    x = random_states(rng, 50)
    u = rng.uniform(0, 3000, 50)
    jac = model.jacobian(x, u)
    scale = np.array([1e-3, 1e-3, 1e-1])
    for j in range(3):
        h = 1e-6 * scale[j]
        e = np.zeros((3, 1))
        e[j] = h
        fd = (model.rhs(x + e, u) - model.rhs(x - e, u)) / (2 * h)
        np.testing.assert_allclose(jac[:, j], fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())


def test_input_jacobian_matches_differences(model):
    x = np.array([8e-4, 1e-3, 0.01])
    h = 1e-3
    fd = (model.rhs(x, 2000 + h) - model.rhs(x, 2000 - h)) / (2 * h)
    np.testing.assert_allclose(model.input_jacobian(x, 2000.0), fd, rtol=1e-6)


def test_vectorised_equals_scalar_calls(model):
    rng = np.random.default_rng(2)
    x = random_states(rng, 7)
    u = rng.uniform(0, 3000, 7)
    batch = model.rhs(x, u)
    for k in range(7):
        f = model.rhs_u2(float(x[0, k]), float(x[1, k]), float(x[2, k]), float(u[k]) ** 2)
        np.testing.assert_allclose(batch[:, k], f, rtol=1e-14)
    assert model.rhs(x.reshape(3, 7, 1), u.reshape(7, 1)).shape == (3, 7, 1)


def test_rest_state_is_a_fixed_point(model):
    for u in (0.0, 2200.0):
        x = static_equilibrium(model.params, u).state
        assert np.max(np.abs(model.rhs(x, u))) < 1e-9


def test_linearisation_at_rest_is_a_lightly_damped_oscillator(model):
    """About 18-21 Hz natural frequency and damping ratio ~0.01 (design notes), one slow real pole."""
    x = static_equilibrium(model.params, 0.0).state
    eig = np.linalg.eigvals(model.jacobian(x, 0.0))
    osc = eig[np.abs(eig.imag) > 0]
    wn = np.abs(osc[0])
    assert 17.0 < wn / (2 * np.pi) < 22.0
    zeta = -osc[0].real / wn
    assert 0.001 < zeta < 0.02
    slow = eig[np.abs(eig.imag) == 0][0].real
    assert slow < 0 and abs(slow) < 2 * model.relax_rate  # the viscoelastic pole


def test_gravity_only_at_flat_membrane():
    m = DEAModel.from_parameters(preset("A2"))
    f = m.rhs(np.zeros(3), 0.0)
    assert f[2] == pytest.approx(9.81)


def test_massless_membrane_is_refused_by_the_dynamic_model():
    with pytest.raises(ValueError, match="mass_kg"):
        DEAModel.from_parameters(preset("A2").replace(mass_kg=0.0))
