"""Sine experiments with the applied waveform: SineSeries.measured_input and SineData.inputs."""
import numpy as np
import pytest

from dea_ros.identify.dynamic_fit import select_fit_frequencies
from dea_ros.identify.experiments import ExperimentError, SineData, SineSeries
from dea_ros.model import preset
from dea_ros.solvers import SinePeriodic, solve_native


def series(freq, applied_amplitude, fs=1000.0, periods=6):
    t = np.arange(0, periods / freq, 1 / fs)
    u = np.abs(applied_amplitude * np.sin(2 * np.pi * freq * t))
    return SineSeries(freq, t, u, np.full(t.size, 7e-4))


def test_measured_input_carries_the_applied_amplitude():
    """Commanded 2.5 kV, applied 3 % less (an amplifier gain error): the response follows the applied."""
    a2 = preset("A2")
    f = 9.0
    inp = series(f, 0.97 * 2500.0).measured_input()
    measured = solve_native(a2, inp, 16, stability=False).displacement_rms()
    applied = solve_native(a2, SinePeriodic(0.97 * 2500.0, f), 8, stability=False).displacement_rms()
    nominal = solve_native(a2, SinePeriodic(2500.0, f), 8, stability=False).displacement_rms()
    assert measured == pytest.approx(applied, rel=2e-4)
    assert abs(nominal - applied) / applied > 0.03  # the nominal sine would be 5 % off here


def test_inputs_reach_the_fit_points():
    s = series(5.0, 2500.0)
    inp = s.measured_input()
    data = SineData([5.0], [2500.0], [1e-4], 0.003, series=(s,), inputs=(inp,))
    (point,) = select_fit_frequencies([data], "all")
    assert point.periodic_input is inp
    plain = SineData([5.0], [2500.0], [1e-4], 0.003)
    assert select_fit_frequencies([plain], "all")[0].periodic_input is None
    with pytest.raises(ExperimentError, match="inputs"):
        SineData([5.0, 6.0], [2500.0, 2500.0], [1e-4, 1e-4], 0.003, inputs=(inp,))


def test_projection_stays_below_nyquist():
    """20 Hz sampled at 500 Hz: 24 harmonics would alias (45 kV 'peaks' seen on a rig bag)."""
    s = series(20.0, 2500.0, fs=500.0, periods=30)
    u = s.measured_input().voltage_V
    assert u.max() < 2500.0 * 1.02 and u.min() >= 0.0
