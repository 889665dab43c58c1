"""Shared fixtures of the control tests: parameter sets unlike the presets."""
import pytest

from dea_ros.model import load_parameters, preset


@pytest.fixture(scope="session")
def unlike():
    """A1 geometry with other material parameters, a 4 g mass and a fast creep (eta1/k1 = 0.1 s)."""
    return preset("A1").replace(name="unlike", relative_permittivity=3.1, k1_Pa=25e6, eta1_Pa_s=2.5e6,
                                eta2_Pa_s=20e3, beta_Pa=(393e3, 267e3, -81.8e3), mass_kg=0.004)


@pytest.fixture(scope="session")
def rig_truth():
    """The mock rig's simulated membrane (A2 with other material parameters)."""
    from dea_ros.model import config_dir

    return load_parameters(config_dir() / "rig" / "mock_membrane.yaml")
