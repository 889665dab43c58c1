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


def held_staircase_record(params, freq, hold_hz=250.0, laser_hz=500.0, settle_s=15.0, measure_s=3.0,
                          amplitude=2500.0, dt=0.5e-3):
    """A rig record by forward integration (RK4, as the mock rig): |U sin| commanded at ``hold_hz``,
    each value held until the next (the amplifier's zero-order hold), the laser sampling at ``laser_hz``.
    Starts on the ideal sine's periodic orbit, so ``settle_s`` leaves no transient above 1e-5."""
    from dea_ros.solvers.integrate import RealTimeStepper

    stepper = RealTimeStepper(params, dt_s=dt)
    stepper.state = [float(x) for x in solve_native(params, SinePeriodic(amplitude, freq), 8,
                                                    stability=False).evaluate(0.0)[:, 0]]
    hold, sample = int(round(1 / (hold_hz * dt))), int(round(1 / (laser_hz * dt)))
    t_rec, u_rec, d_rec = [], [], []
    u = 0.0
    for i in range(int(round((settle_s + measure_s) / dt))):
        if i % hold == 0:
            u = abs(amplitude * np.sin(2 * np.pi * freq * i * dt))
        if i % sample == 0 and i * dt >= settle_s:
            t_rec.append(i * dt - settle_s)
            u_rec.append(u)
            d_rec.append(stepper.displacement_m)
        stepper.step(u)
    return np.array(t_rec), np.array(u_rec), np.array(d_rec)


@pytest.mark.parametrize("freq", [9.5, 11.2])
def test_held_input_is_the_realised_excitation(freq):
    """The rig holds each command for 4 ms (250 Hz): u^2 of the staircase has its 2f component
    attenuated by sinc(2 f / 250 Hz) and delayed by half a step. The held input (exact integrals of
    the staircase) reproduces the integrated d_rms and the sampled curve; the ideal sine and the
    least-squares projection of the samples do not (membrane X7, unlike the presets)."""
    from .conftest import UNLIKE
    from dea_ros.solvers.integrate import initial_state

    t, u, d = held_staircase_record(UNLIKE, freq)
    d0 = initial_state(UNLIKE, 0.0)[0]
    held = SineSeries(freq, t, u, d, voltage_hold="zoh")
    truth = held.displacement_rms(d0)
    sol = solve_native(UNLIKE, held.measured_input(), 16, stability=False)
    assert sol.displacement_rms(d0) == pytest.approx(truth, rel=1e-4)
    # the model curve at the samples, no alignment: the input's phase 0 is the record start
    assert np.sqrt(np.mean((sol.evaluate(t)[0] - d) ** 2)) < 1e-3 * truth
    ideal = solve_native(UNLIKE, SinePeriodic(2500.0, freq), 8, stability=False).displacement_rms(d0)
    projected = solve_native(UNLIKE, SineSeries(freq, t, u, d).measured_input(), 16,
                             stability=False).displacement_rms(d0)
    assert abs(ideal / truth - 1) > 2e-3        # what fitting the ideal sine would get wrong
    assert abs(projected / truth - 1) > 5e-4    # and the projection of the point samples
