"""model_node's predictor without ROS: exact updates at input stamps, extrapolation, late and stale inputs, gaps."""
import pytest

from dea_ros.control.prediction import ModelPredictor
from dea_ros.model import preset
from dea_ros.solvers.integrate import RealTimeStepper

MS = 1_000_000


def test_inputs_on_the_step_grid_equal_the_stepper():
    predictor = ModelPredictor(preset("A2"), 1e-3, 1.0)
    stepper = RealTimeStepper(preset("A2"), dt_s=1e-3)
    voltages = [0.0, 1000.0, 2500.0, 2500.0, 500.0]
    expected = [stepper.displacement_m] + [stepper.step(u) for u in voltages[:-1]]
    got = []
    for k, u in enumerate(voltages):
        assert predictor.input(k * MS, u)
        got.append(predictor.displacement_m)
    assert got == expected and predictor.voltage_V == 500.0


def test_a_late_input_replaces_the_extrapolation_and_a_stale_one_is_ignored():
    predictor = ModelPredictor(preset("A2"), 1e-3, 1.0)
    predictor.input(0, 2000.0)
    predictor.extrapolate(10 * MS)                  # 10 ms at 2000 V
    assert predictor.model_time_ns == 10 * MS
    predictor.input(4 * MS, 0.0)                    # arrived late: 4 ms at 2000 V, then 0 V is held
    reference = RealTimeStepper(preset("A2"), dt_s=1e-3)
    for _ in range(4):
        reference.step(2000.0)
    assert predictor.stepper.state == reference.state and predictor.model_time_ns == 4 * MS
    assert not predictor.input(3 * MS, 1000.0)      # older than the anchor
    assert predictor.stale_inputs == 1 and predictor.voltage_V == 0.0


def test_steps_off_the_grid_end_with_a_shorter_step():
    predictor = ModelPredictor(preset("A2"), 1e-3, 1.0)
    predictor.input(0, 2000.0)
    predictor.input(2 * MS + 400_000, 2000.0)
    reference = RealTimeStepper(preset("A2"), dt_s=1e-3)
    reference.step(2000.0)
    reference.step(2000.0)
    reference.step(2000.0, 0.4e-3)
    assert predictor.stepper.state == pytest.approx(reference.state, rel=1e-15)


def test_a_long_gap_restarts_at_the_equilibrium_of_the_held_voltage():
    gaps = []
    predictor = ModelPredictor(preset("A2"), 1e-3, 0.5, on_gap_reset=lambda gap, u: gaps.append((gap, u)))
    predictor.input(0, 1500.0)
    predictor.input(600 * MS, 0.0)
    assert gaps == [(600 * MS, 1500.0)] and predictor.resets_for_gaps == 1
    assert predictor.stepper.state == RealTimeStepper(preset("A2"), initial_voltage_V=1500.0).state
    predictor.extrapolate(2000 * MS)                # more than max_catch_up_s behind: equilibrium at 0 V
    assert predictor.stepper.state == RealTimeStepper(preset("A2")).state


def test_restart_and_reset():
    predictor = ModelPredictor(preset("A2"), 1e-3, 1.0)
    predictor.input(0, 2000.0)
    predictor.extrapolate(5 * MS)
    predictor.reset()
    assert predictor.anchor_state == RealTimeStepper(preset("A2"), initial_voltage_V=2000.0).state
    predictor.restart()
    assert (predictor.model_time_ns, predictor.anchor_ns, predictor.anchor_state) == (None, None, None)
    predictor.start_clock(7 * MS)
    assert predictor.behind_s(8 * MS) == pytest.approx(1e-3)
    predictor.replace_model(preset("LP1"))
    assert predictor.params.name == preset("LP1").name
