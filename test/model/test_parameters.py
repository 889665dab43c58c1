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


# ---------------------------------------------------------------- plausibility (unit slips)
def _file(tmp_path, **changes):
    import yaml

    data = preset("A1").to_dict()
    data.update(changes)
    for key in [k for k, v in changes.items() if v is None]:
        del data[key]
    path = tmp_path / "membrane.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    "change, message",
    [
        ({"thickness_m": 2.7e-4}, r"thickness_m.*10 x the value 2.7e-05 of the paper's membrane A1"),  # x10 slip
        ({"name": "mine", "thickness_m": 2.7e-3}, r"thickness_m.*1-1000 um.*micrometres or millimetres"),
        ({"name": "mine", "thickness_m": 0.5e-6}, r"thickness_m.*1-1000 um"),
        ({"prestretch": 1e-300}, r"prestretch.*stretch ratio >= 1"),
        ({"name": "mine", "prestretch": 19.0}, r"prestretch.*not a percentage"),
        ({"k1_Pa": 69.89}, r"k1_Pa.*69.89 Pa.*MPa"),                          # k1 in MPa
        ({"eta1_Pa_s": 5.39}, r"eta1_Pa_s.*MPa s"),
        ({"eta2_Pa_s": 0.01635}, r"eta2_Pa_s.*kPa s or MPa s"),
        ({"beta_Pa": [0.343, 0.267, -0.0818]}, r"beta_Pa.*given in MPa"),
        ({"gamma_Pa": [1.34e12, 0.0, 0.0]}, r"gamma_Pa.*exponent"),
        ({"breakdown_field_V_per_m": 8e8}, r"breakdown_field_V_per_m.*8e\+08.*3e\+08.*(80 V/um -> 8e7)"),
        ({"breakdown_field_V_per_m": 1e10}, r"breakdown_field_V_per_m"),
        ({"breakdown_field_V_per_m": 100.0}, r"breakdown_field_V_per_m.*V/um"),
        ({"mass_kg": 3.0}, r"mass_kg.*grams"),
        ({"relative_permittivity": 2.3e-11}, r"relative_permittivity"),
        ({"vacuum_permittivity_F_per_m": 8.85}, r"vacuum_permittivity_F_per_m.*8.854e-12"),
        ({"name": "mine", "plate_radius_m": 4.5}, r"plate_radius_m.*millimetres"),
    ],
)
def test_unit_slips_in_files_are_refused_naming_field_and_slip(tmp_path, change, message):
    with pytest.raises(ParameterError, match=message):
        load_parameters(_file(tmp_path, **change))


def test_every_shipped_membrane_file_is_plausible():
    from dea_ros.model import config_dir

    files = sorted((config_dir() / "membranes").glob("*.yaml")) + sorted((config_dir() / "rig").glob("*.yaml"))
    assert len(files) >= 4
    for path in files:
        params = load_parameters(str(path), require=("breakdown_field_V_per_m",))
        assert params.plausibility_problems() == []


def test_other_names_may_have_other_geometry_and_fits_may_leave_the_ranges(tmp_path):
    p = load_parameters(_file(tmp_path, name="thick film", thickness_m=2.7e-4))
    assert p.thickness_m == 2.7e-4
    # construction (replace) inside a fit checks validity only, not plausibility
    q = preset("A2").replace(k1_Pa=1.0, eta2_Pa_s=0.0)
    assert q.plausibility_problems() and q.k1_Pa == 1.0


def test_breakdown_field_can_be_required(tmp_path):
    path = _file(tmp_path, breakdown_field_V_per_m=None)
    assert load_parameters(path).breakdown_field_V_per_m == 100e6  # the model alone may default it
    with pytest.raises(ParameterError, match=r"missing field.*breakdown_field_V_per_m.*never defaulted"):
        load_parameters(path, require=("breakdown_field_V_per_m",))


def test_margin_must_be_strictly_below_one():
    with pytest.raises(ParameterError, match="strictly below 1"):
        preset("A2").max_safe_voltage_V(1.0)
