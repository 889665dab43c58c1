"""Parameters: presets from Tables I-II, YAML round trip, validation messages."""
import math

import pytest

from dea_ros.model import PRESET_NAMES, MembraneParameters, ParameterError, load_parameters, preset


def test_presets_match_tables_I_and_II():
    lp1, a1, a2 = (preset(n) for n in ("LP1", "A1", "A2"))
    assert (lp1.prestretch, lp1.thickness_m, lp1.electrode_width_m) == (1.15, 38e-6, 14e-3)
    assert (a1.prestretch, a1.thickness_m, a1.electrode_width_m) == (1.36, 27e-6, 17e-3)
    assert a2.plate_radius_m == 4.5e-3 and a2.mass_kg == 3e-3
    assert a2.k1_Pa == pytest.approx(40.25e6) and a2.eta1_Pa_s == pytest.approx(37.58e6)
    assert a2.eta2_Pa_s == pytest.approx(35.11e3) and a2.relative_permittivity == 2.63
    assert lp1.beta_Pa == pytest.approx((110e3, -86.7e3, 267e3))
    assert a1.gamma_Pa == pytest.approx((134e3, -396e3, -245e3))


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_yaml_round_trip(tmp_path, name):
    p = preset(name)
    path = tmp_path / "p.yaml"
    p.to_yaml(path, header="test")
    q = MembraneParameters.from_yaml(path)
    assert q == p
    assert load_parameters(str(path)) == p
    assert load_parameters(name.lower()) == p


def test_derived_quantities():
    p = preset("A2")
    assert p.c1bar_m == pytest.approx(2 * math.pi * 4.5e-3 * 35e-6 / 17e-3)
    assert p.c2_Pa_per_V2 == pytest.approx(-8.85e-12 * 2.63 / 35e-6**2)
    assert p.breakdown_voltage_V() == pytest.approx(3500.0)
    assert p.max_safe_voltage_V(0.9) == pytest.approx(3150.0)
    beta, gamma = MembraneParameters.ogden_beta_gamma_from_mu([1.0, 2.0, 3.0], 1.2)
    assert beta[1] == pytest.approx(2.0 * 1.2**4) and gamma[2] == pytest.approx(3.0 * 1.2**-12)


@pytest.mark.parametrize(
    "change, field",
    [
        ({"thickness_m": -1e-6}, "thickness_m"),
        ({"thickness_m": 35.0}, "thickness_m"),          # micrometres typed as metres
        ({"mass_kg": 3.0 * 1000}, "mass_kg"),            # grams slip beyond 10 kg
        ({"mass_kg": float("nan")}, "mass_kg"),
        ({"k1_Pa": float("inf")}, "k1_Pa"),
        ({"electrode_width_m": 17.0}, "electrode_width_m"),
        ({"beta_Pa": (1.0, 2.0)}, "beta_Pa"),
        ({"gamma_Pa": (1.0, float("nan"), 3.0)}, "gamma_Pa[1]"),
        ({"relative_permittivity": 0.0}, "relative_permittivity"),
    ],
)
def test_invalid_values_name_the_field(change, field):
    with pytest.raises(ParameterError, match=field.replace("[", r"\[").replace("]", r"\]")):
        preset("A2").replace(**change)


def test_missing_and_unknown_keys(tmp_path):
    d = preset("A2").to_dict()
    del d["k1_Pa"]
    with pytest.raises(ParameterError, match="missing field.*k1_Pa"):
        MembraneParameters.from_dict(d)
    d = preset("A2").to_dict()
    d["k2_Pa"] = 1.0
    with pytest.raises(ParameterError, match="unknown field.*k2_Pa"):
        MembraneParameters.from_dict(d)
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ParameterError, match="not valid YAML"):
        MembraneParameters.from_yaml(bad)
    with pytest.raises(ParameterError, match="no such parameters file"):
        load_parameters(tmp_path / "missing.yaml")
    with pytest.raises(ParameterError, match="unknown membrane preset"):
        preset("B7")


def test_nested_membrane_section(tmp_path):
    import yaml

    path = tmp_path / "nested.yaml"
    path.write_text(yaml.safe_dump({"membrane": preset("LP1").to_dict(), "other": {"x": 1}}))
    assert MembraneParameters.from_yaml(path) == preset("LP1")
