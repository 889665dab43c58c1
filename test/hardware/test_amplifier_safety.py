"""Tests of dea_ros.hardware.amplifier.limits and .safety: limits, the safe voltage state machine, fuzzing."""
from __future__ import annotations

import math
import random

import numpy as np
import pytest

from dea_ros.errors import SafetyConfigError
from dea_ros.hardware.amplifier.limits import SafetyLimits, membrane_voltage_limit_V
from dea_ros.hardware.amplifier.safety import ControlClock, ControllerState, RejectionReason, SafeVoltageController, \
    drive_to_zero

LIMITS = SafetyLimits(
    max_voltage_V=3000.0, slew_rate_V_per_s=1000.0, watchdog_timeout_s=0.5, ramp_down_rate_V_per_s=500.0
)


def make(limits: SafetyLimits = LIMITS, active_at: float | None = 0.0) -> SafeVoltageController:
    controller = SafeVoltageController(limits)
    if active_at is not None:
        controller.activate(active_at)
        controller.update(active_at)
    return controller


# =========================================================================== SafetyLimits
class TestSafetyLimits:
    def test_valid_limits_are_stored_as_floats(self):
        limits = SafetyLimits(3000, 1000, 1, 500)
        assert limits.max_voltage_V == 3000.0 and isinstance(limits.max_voltage_V, float)
        assert limits.slew_rate_V_per_s == 1000.0
        assert limits.watchdog_timeout_s == 1.0
        assert limits.ramp_down_rate_V_per_s == 500.0
        assert limits.membrane_limit_V is None

    @pytest.mark.parametrize(
        "field", ["max_voltage_V", "slew_rate_V_per_s", "watchdog_timeout_s", "ramp_down_rate_V_per_s"]
    )
    @pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), 0.0, -1.0, True, "5", None])
    def test_invalid_field_is_refused_naming_the_field(self, field, bad):
        values = dict(max_voltage_V=3000.0, slew_rate_V_per_s=1000.0, watchdog_timeout_s=0.5,
                      ramp_down_rate_V_per_s=500.0)
        values[field] = bad
        with pytest.raises(SafetyConfigError, match=field):
            SafetyLimits(**values)

    def test_ramp_down_faster_than_slew_is_refused(self):
        with pytest.raises(SafetyConfigError, match="ramp_down_rate_V_per_s.*slew_rate_V_per_s"):
            SafetyLimits(3000.0, 1000.0, 0.5, 1000.1)
        assert SafetyLimits(3000.0, 1000.0, 0.5, 1000.0).ramp_down_rate_V_per_s == 1000.0

    def test_unit_slips_are_refused(self):
        with pytest.raises(SafetyConfigError, match="max_voltage_V.*SI volts"):
            SafetyLimits(3e6, 1000.0, 0.5, 500.0)
        with pytest.raises(SafetyConfigError, match="watchdog_timeout_s.*500 ms"):
            SafetyLimits(3000.0, 1000.0, 500.0, 500.0)

    def test_limits_are_immutable(self):
        with pytest.raises(Exception):
            LIMITS.max_voltage_V = 1e4  # type: ignore[misc]

    def test_from_membrane_derives_margin_field_thickness(self):
        limits = SafetyLimits.from_membrane(27e-6, 100e6, 0.9, slew_rate_V_per_s=2000.0,
                                            watchdog_timeout_s=0.2)
        assert limits.max_voltage_V == pytest.approx(2430.0, rel=1e-12)
        assert limits.membrane_limit_V == pytest.approx(2430.0, rel=1e-12)
        assert limits.ramp_down_rate_V_per_s == 2000.0  # defaults to the slew rate
        assert membrane_voltage_limit_V(27e-6, 100e6, 0.5) == pytest.approx(1350.0)

    def test_from_membrane_accepts_lower_configured_max(self):
        limits = SafetyLimits.from_membrane(27e-6, 100e6, 0.9, slew_rate_V_per_s=2000.0,
                                            watchdog_timeout_s=0.2, ramp_down_rate_V_per_s=800.0,
                                            max_voltage_V=2000.0)
        assert limits.max_voltage_V == 2000.0
        assert limits.ramp_down_rate_V_per_s == 800.0

    def test_from_membrane_refuses_configured_max_above_derived_limit(self):
        with pytest.raises(SafetyConfigError) as info:
            SafetyLimits.from_membrane(27e-6, 100e6, 0.9, slew_rate_V_per_s=2000.0,
                                       watchdog_timeout_s=0.2, max_voltage_V=2500.0)
        message = str(info.value)
        assert "max_voltage_V" in message and "2430" in message and "membrane limit" in message

    @pytest.mark.parametrize(
        "thickness_m, field_V_per_m, margin, culprit",
        [
            (27.0, 100e6, 0.9, "thickness_m"),  # micrometres given as metres
            (27e-6, 100.0, 0.9, "breakdown_field_V_per_m"),  # V/um given as V/m
            (27e-6, 100e6, 0.0, "margin"),
            (27e-6, 100e6, 1.5, "margin"),
            (27e-6, 100e6, 1.0, "margin.*strictly below 1"),  # no headroom
            (27e-6, 8e8, 0.9, "breakdown_field_V_per_m.*8e7"),  # exponent typo: 25 kV on A1
            (27e-6, 1e10, 0.9, "breakdown_field_V_per_m"),
            (2e-3, 100e6, 0.9, "thickness_m.*1-1000 um"),
            (0.5e-6, 100e6, 0.9, "thickness_m"),
            (27e-6, float("nan"), 0.9, "breakdown_field_V_per_m"),
        ],
    )
    def test_from_membrane_validates_inputs(self, thickness_m, field_V_per_m, margin, culprit):
        with pytest.raises(SafetyConfigError, match=culprit):
            SafetyLimits.from_membrane(thickness_m, field_V_per_m, margin, slew_rate_V_per_s=1000.0,
                                       watchdog_timeout_s=0.5)

    def test_ramp_to_zero_must_finish_in_bounded_time_after_the_watchdog(self):
        # the reproduction: ramp 1 V/s and a 60 s watchdog took 53 minutes to reach 0 V
        with pytest.raises(SafetyConfigError, match=r"watchdog_timeout_s.*3210 s.*lower watchdog_timeout_s"):
            SafetyLimits.from_membrane(35e-6, 100e6, 0.9, slew_rate_V_per_s=1e5, watchdog_timeout_s=60.0,
                                       ramp_down_rate_V_per_s=1.0)
        with pytest.raises(SafetyConfigError, match=r"ramp_down_rate_V_per_s.*3150 s.*at least 331.6 V/s"):
            SafetyLimits.from_membrane(35e-6, 100e6, 0.9, slew_rate_V_per_s=1e5, watchdog_timeout_s=0.5,
                                       ramp_down_rate_V_per_s=1.0)
        limits = SafetyLimits.from_membrane(35e-6, 100e6, 0.9, slew_rate_V_per_s=1e5, watchdog_timeout_s=0.5,
                                            ramp_down_rate_V_per_s=1e4)
        assert limits.watchdog_timeout_s + limits.time_to_zero_s(limits.max_voltage_V) <= 10.0

    def test_direct_construction_checks_membrane_limit(self):
        with pytest.raises(SafetyConfigError, match="membrane limit"):
            SafetyLimits(3000.0, 1000.0, 0.5, 500.0, membrane_limit_V=2430.0)

    def test_from_membrane_parameters_uses_the_model_preset(self):
        from dea_ros.model.parameters import preset

        params = preset("A1")
        limits = SafetyLimits.from_membrane_parameters(params, 0.9, slew_rate_V_per_s=1500.0,
                                                       watchdog_timeout_s=0.3)
        assert limits.max_voltage_V == pytest.approx(params.max_safe_voltage_V(0.9), rel=1e-12)

    def test_from_dict_round_trip_and_errors(self):
        assert SafetyLimits.from_dict(LIMITS.to_dict()) == LIMITS
        with pytest.raises(SafetyConfigError, match="unknown field.*max_voltage_kV"):
            SafetyLimits.from_dict({**LIMITS.to_dict(), "max_voltage_kV": 3.0})
        with pytest.raises(SafetyConfigError, match="missing field.*watchdog_timeout_s"):
            SafetyLimits.from_dict({"max_voltage_V": 1.0, "slew_rate_V_per_s": 1.0,
                                    "ramp_down_rate_V_per_s": 1.0})


# =========================================================================== controller basics
class TestActivation:
    def test_starts_inactive_at_zero_and_rejects_commands(self):
        controller = SafeVoltageController(LIMITS)
        assert controller.state is ControllerState.INACTIVE
        assert controller.update(0.0) == 0.0
        result = controller.command(1000.0, 0.1)
        assert not result and result.reason == "inactive"
        assert controller.target_V == 0.0
        assert controller.update(10.0) == 0.0
        assert controller.rejected_counts["inactive"] == 1

    def test_rejects_non_limits(self):
        with pytest.raises(TypeError, match="SafetyLimits"):
            SafeVoltageController({"max_voltage_V": 1.0})  # type: ignore[arg-type]

    def test_ramps_up_at_exactly_the_slew_rate(self):
        controller = make()
        assert controller.command(2000.0, 0.0).accepted
        outputs = []
        for k in range(1, 31):
            controller.command(2000.0, 0.1 * k)  # keep the watchdog fed
            outputs.append(controller.update(0.1 * k))
        # 1000 V/s: 100 V per 0.1 s until the 2000 V target, then it stays there.
        expected = [min(100.0 * k, 2000.0) for k in range(1, 31)]
        assert outputs == pytest.approx(expected, rel=1e-9)
        assert outputs[-1] == 2000.0

    def test_lowering_the_target_moves_down_at_slew_rate(self):
        controller = make()
        controller.command(1000.0, 0.0)
        for k in range(1, 11):
            controller.command(1000.0, 0.1 * k)
            controller.update(0.1 * k)
        assert controller.output_V == pytest.approx(1000.0)
        controller.command(0.0, 1.0)
        assert controller.update(1.1) == pytest.approx(900.0)  # slew 1000 V/s, not ramp 500 V/s
        assert controller.state is ControllerState.ACTIVE

    def test_deactivate_ramps_down_at_ramp_rate_then_inactive(self):
        controller = make()
        controller.command(1000.0, 0.0)
        for k in range(1, 11):
            controller.command(1000.0, 0.1 * k)
            controller.update(0.1 * k)
        controller.deactivate(1.0)
        assert controller.state is ControllerState.RAMPING_DOWN
        assert controller.target_V == 0.0
        assert controller.update(1.5) == pytest.approx(750.0)  # 500 V/s
        assert controller.command(1000.0, 1.6).reason == "inactive"
        assert controller.update(2.9) == pytest.approx(50.0)
        assert controller.update(3.0) == 0.0
        assert controller.state is ControllerState.INACTIVE

    def test_deactivate_at_zero_is_inactive_immediately(self):
        controller = make()
        controller.deactivate(0.1)
        assert controller.state is ControllerState.INACTIVE

    def test_activate_is_idempotent_and_starts_from_zero_target(self):
        controller = make()
        controller.command(500.0, 0.0)
        controller.activate(0.1)  # already active: no change
        assert controller.target_V == 500.0
        controller.deactivate(0.2)
        controller.activate(0.3)
        assert controller.state is ControllerState.ACTIVE
        assert controller.target_V == 0.0


class TestCommandValidation:
    @pytest.mark.parametrize(
        "value, reason",
        [
            (float("nan"), "nan"),
            (np.nan, "nan"),
            (float("inf"), "infinite"),
            (-float("inf"), "infinite"),
            (-1.0, "negative"),
            (-1e-300, "negative"),
            (3000.0000001, "above_max"),
            (math.nextafter(3000.0, math.inf), "above_max"),
            (1e4, "above_max"),
            ("1000", "invalid_type"),
            (None, "invalid_type"),
            (True, "invalid_type"),
            (1 + 2j, "invalid_type"),
            ([1000.0], "invalid_type"),
        ],
    )
    def test_invalid_commands_are_rejected_counted_and_do_not_move_the_target(self, value, reason):
        controller = make()
        assert controller.command(1234.0, 0.0).accepted
        state_before = controller.state
        result = controller.command(value, 0.1)
        assert not result.accepted and result.reason == reason
        assert result.target_V == 1234.0 and controller.target_V == 1234.0
        assert controller.state is state_before
        assert controller.rejected_counts[reason] == 1
        assert sum(controller.rejected_counts.values()) == 1
        assert controller.accepted_count == 1

    @pytest.mark.parametrize("value", [0.0, -0.0, 3000.0, 1, np.float64(12.5), np.float32(12.5), np.int64(7)])
    def test_valid_commands_set_the_target(self, value):
        controller = make()
        result = controller.command(value, 0.0)
        assert result.accepted and result.reason == "accepted"
        assert controller.target_V == float(value)
        assert math.copysign(1.0, controller.target_V) == 1.0  # -0.0 stored as +0.0

    def test_every_reason_is_counted_separately(self):
        controller = make()
        for value in (math.nan, math.nan, math.inf, -5.0, 4000.0, "x"):
            controller.command(value, 0.0)
        controller.deactivate(0.0)
        controller.command(100.0, 0.0)
        assert controller.rejected_counts == {
            "invalid_type": 1, "nan": 2, "infinite": 1, "negative": 1, "above_max": 1, "inactive": 1
        }
        assert set(controller.rejected_counts) == {r.value for r in RejectionReason}

    @pytest.mark.parametrize("bad_t", [math.nan, math.inf, -math.inf])
    def test_non_finite_time_raises(self, bad_t):
        controller = make()
        for call in (controller.update, controller.activate, controller.deactivate,
                     controller.emergency_ramp_down, lambda t: controller.command(1.0, t)):
            with pytest.raises(ValueError, match="finite"):
                call(bad_t)

    def test_non_numeric_time_raises_type_error(self):
        with pytest.raises(TypeError, match="time in seconds"):
            make().update("1.0")  # type: ignore[arg-type]


class TestWatchdog:
    def test_trips_after_timeout_and_ramps_down_at_ramp_rate(self):
        controller = make()
        controller.command(1000.0, 0.0)
        controller.command(1000.0, 0.4)
        assert controller.update(0.4) == pytest.approx(400.0)
        assert controller.update(0.9) == pytest.approx(900.0)  # silence 0.5 s == timeout: not yet
        assert controller.state is ControllerState.ACTIVE
        assert controller.update(1.0) == pytest.approx(850.0)  # silence 0.6 s: tripped, -500 V/s
        assert controller.state is ControllerState.WATCHDOG_TRIPPED
        assert controller.target_V == 0.0
        assert controller.watchdog_trip_count == 1
        assert controller.update(2.7) == pytest.approx(0.0, abs=1e-9)
        assert controller.update(2.71) == 0.0

    def test_valid_command_clears_trip_and_rises_again(self):
        controller = make()
        controller.command(1000.0, 0.0)
        controller.update(0.5)
        controller.update(1.2)
        assert controller.state is ControllerState.WATCHDOG_TRIPPED
        before = controller.output_V
        assert controller.command(1000.0, 1.2).accepted
        assert controller.state is ControllerState.ACTIVE
        assert controller.update(1.3) == pytest.approx(before + 100.0)

    def test_rejected_commands_do_not_feed_the_watchdog(self):
        controller = make()
        controller.command(1000.0, 0.0)
        for k in range(1, 20):
            controller.command(math.nan, 0.1 * k)
            controller.command(5000.0, 0.1 * k)
            controller.update(0.1 * k)
        assert controller.state is ControllerState.WATCHDOG_TRIPPED

    def test_regular_commands_keep_it_alive_indefinitely(self):
        controller = make()
        for k in range(1, 2000):
            controller.command(2000.0, 0.25 * k)
            controller.update(0.25 * k)
        assert controller.state is ControllerState.ACTIVE
        assert controller.output_V == 2000.0
        assert controller.watchdog_trip_count == 0

    def test_activation_starts_the_watchdog(self):
        controller = make(active_at=10.0)
        controller.update(10.6)
        assert controller.state is ControllerState.WATCHDOG_TRIPPED


class TestClock:
    def test_backward_jump_gives_no_movement_then_rebases(self):
        controller = make()
        controller.command(3000.0, 0.0)
        controller.command(3000.0, 0.4)
        u1 = controller.update(0.4)
        assert controller.update(0.1) == u1  # clock went back 0.3 s
        assert controller.clock_backward_jump_count == 1
        controller.command(3000.0, 0.1)
        assert controller.update(0.2) == pytest.approx(u1 + 100.0)  # measured from the new clock

    def test_repeated_time_gives_no_movement(self):
        controller = make()
        controller.command(3000.0, 0.0)
        u = controller.update(0.3)
        for _ in range(100):
            assert controller.update(0.3) == u

    def test_backward_jump_does_not_freeze_ramp_down(self):
        controller = make()
        controller.command(1000.0, 0.0)
        controller.command(1000.0, 0.4)
        controller.update(0.4)
        controller.deactivate(0.4)
        controller.update(-1000.0)  # clock reset far into the past
        assert controller.update(-999.0) == 0.0  # 400 V at 500 V/s: 0.8 s

    def test_backward_jump_does_not_blind_the_watchdog(self):
        controller = make()
        controller.command(1000.0, 100.0)
        controller.update(100.0)
        controller.update(0.0)  # clock reset
        controller.update(0.6)  # 0.6 s of silence on the new clock
        assert controller.state is ControllerState.WATCHDOG_TRIPPED

    def test_huge_dt_and_overflowing_step(self):
        fast = SafetyLimits(1000.0, 1e308, 50.0, 1e308)
        controller = make(fast)
        controller.command(1000.0, 0.0)
        assert controller.update(10.0) == 1000.0  # 1e308 V/s x 10 s overflows to inf: still exact
        controller = make()
        controller.command(1000.0, 0.0)
        controller.update(0.3)
        assert controller.update(1e300) == 0.0  # watchdog tripped long ago; ramp complete
        assert controller.state is ControllerState.WATCHDOG_TRIPPED

    def test_huge_forward_glitch_does_not_blind_the_watchdog_later(self):
        """One forward clock glitch of 1e14 s (or many large alternations) used to make later
        increments vanish in the accumulator's floating point: the watchdog never tripped again."""
        controller = make()
        controller.command(1000.0, 0.0)
        controller.update(1e14)  # glitch: trips (silence 1e14 s)
        assert controller.state is ControllerState.WATCHDOG_TRIPPED
        t = 1e14
        controller.command(1000.0, t)  # commands resume on the glitched clock
        for k in range(1, 2000):  # 1 ms steps (quantised to 1/64 s at 1e14), no command
            controller.update(t + 1e-3 * k)
            if controller.state is ControllerState.WATCHDOG_TRIPPED:
                break
        assert controller.state is ControllerState.WATCHDOG_TRIPPED and 500 <= k <= 520
        # many large alternations, then small steps on a normal clock
        controller = make()
        for k in range(200):
            controller.command(500.0, 0.0 if k % 2 else 1e15)
            controller.update(0.0 if k % 2 else 1e15)
        controller.command(500.0, 0.0)
        controller.update(0.0)
        steps = 0
        while controller.state is ControllerState.ACTIVE and steps < 10_000:
            steps += 1
            controller.update(1e-3 * steps)
        assert controller.state is ControllerState.WATCHDOG_TRIPPED and 500 <= steps <= 502

    def test_large_time_offsets(self):
        controller = make(active_at=1e9)
        controller.command(3000.0, 1e9)
        assert controller.update(1e9 + 0.25) == pytest.approx(250.0, rel=1e-6)

    def test_slew_bound_is_exact_in_floating_point(self):
        rng = random.Random(7)
        for _ in range(200):
            slew = rng.uniform(0.01, 1e5)
            limits = SafetyLimits(5000.0, slew, 60.0, slew * rng.uniform(0.01, 1.0))
            controller = make(limits, active_at=rng.uniform(0, 1e6))
            t_prev, u_prev = controller.last_update_t_s, controller.output_V
            for _ in range(30):
                t = t_prev + rng.choice([rng.uniform(0, 1e-3), rng.uniform(0, 1.0), 1e-9])
                controller.command(rng.uniform(0, 5000.0), t)
                u = controller.update(t)
                assert abs(u - u_prev) <= slew * (t - t_prev)  # no tolerance
                t_prev, u_prev = t, u


class TestEmergencyAndDiagnostics:
    def test_emergency_ramp_down_returns_time_to_zero_and_latches(self):
        controller = make()
        controller.command(1000.0, 0.0)
        controller.command(1000.0, 0.4)
        controller.update(0.4)
        needed_s = controller.emergency_ramp_down(0.4)
        assert needed_s == pytest.approx(400.0 / 500.0)
        assert controller.state is ControllerState.EMERGENCY_STOP
        assert controller.command(100.0, 0.5).reason == "inactive"
        controller.deactivate(0.5)
        assert controller.state is ControllerState.EMERGENCY_STOP
        assert controller.update(0.4 + needed_s / 2) == pytest.approx(200.0)
        assert controller.update(0.4 + needed_s) == pytest.approx(0.0, abs=1e-9)
        assert controller.update(0.4 + needed_s + 1e-9) == 0.0
        assert controller.state is ControllerState.EMERGENCY_STOP
        assert controller.emergency_ramp_down(5.0) == 0.0
        controller.activate(6.0)
        assert controller.state is ControllerState.ACTIVE

    def test_diagnostics_snapshot(self):
        controller = make()
        diag = controller.diagnostics()
        assert diag.last_command_age_s is None
        controller.command(1000.0, 0.0)
        controller.command(-1.0, 0.0)
        controller.update(0.2)
        diag = controller.diagnostics()
        assert diag.state == "active"
        assert diag.target_V == 1000.0
        assert diag.output_V == pytest.approx(200.0)
        assert diag.accepted_count == 1
        assert diag.rejected_counts["negative"] == 1 and diag.rejected_total == 1
        assert diag.last_command_age_s == pytest.approx(0.2)
        assert controller.diagnostics(0.45).last_command_age_s == pytest.approx(0.45)
        assert controller.update(0.3) == pytest.approx(300.0)  # diagnostics(t) did not advance time
        assert diag.time_to_zero_s == pytest.approx(200.0 / 500.0)
        pairs = dict(diag.key_values())
        assert pairs["state"] == "active" and pairs["rejected_counts.negative"] == "1"
        assert all(isinstance(v, str) for v in pairs.values())
        diag.rejected_counts["nan"] = 99  # a snapshot: mutating it does not touch the controller
        assert controller.rejected_counts["nan"] == 0

    def test_drive_to_zero_with_injected_clock(self):
        controller = make()
        controller.command(1000.0, 0.0)
        controller.command(1000.0, 0.4)
        controller.update(0.4)
        now = [0.4]
        written = []

        def sleep(dt):
            now[0] += dt

        final = drive_to_zero(controller, written.append, lambda: now[0], sleep, period_s=0.01)
        assert final == 0.0 and written[-1] == 0.0
        assert all(b <= a for a, b in zip(written, written[1:]))
        assert all(a - b <= 500.0 * 0.01 * (1 + 1e-9) for a, b in zip(written, written[1:]))
        assert now[0] - 0.4 == pytest.approx(0.8, abs=0.011)

    def test_drive_to_zero_terminates_with_a_frozen_clock(self):
        controller = make()
        controller.command(1000.0, 0.0)
        controller.update(0.4)
        calls = []
        final = drive_to_zero(controller, calls.append, lambda: 0.4, lambda dt: None, period_s=0.1)
        assert final == calls[-1] > 0.0
        assert len(calls) < 200


# =========================================================================== property fuzzing
def _approach(u: float, goal: float, step: float) -> float:
    return goal if abs(goal - u) <= step else u + math.copysign(step, goal - u)


def _predicted_reason(value, max_V: float, activated: bool):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        return "invalid_type"
    v = float(value)
    if v != v:
        return "nan"
    if v in (math.inf, -math.inf):
        return "infinite"
    if v < 0:
        return "negative"
    if v > max_V:
        return "above_max"
    if not activated:
        return "inactive"
    return None


def _random_value(rng: random.Random, max_V: float):
    r = rng.random()
    if r < 0.30:
        return rng.uniform(-1e4, 1e4)
    if r < 0.70:
        return rng.uniform(0.0, max_V)
    return rng.choice([
        max_V, 0.0, -0.0, math.nextafter(max_V, math.inf), math.nan, math.inf, -math.inf, -1e-300,
        np.float64(max_V / 2), np.float32(1.0), 7, "3", None, True,
    ])


class _FuzzChecker:
    """Drives one random stream and checks every invariant after each call."""

    def __init__(self, rng: random.Random):
        self.rng = rng
        max_V = rng.uniform(10.0, 5000.0)
        slew = 10 ** rng.uniform(0, 4)
        self.limits = SafetyLimits(max_V, slew, rng.uniform(0.01, 5.0), slew * rng.uniform(0.05, 1.0))
        self.c = SafeVoltageController(self.limits)
        self.tol_V = 1e-9 * max_V
        self.t = rng.choice([0.0, rng.uniform(0, 1e6), 1e9])
        # Independent model of what the controller must do.
        self.activated = False
        self.tripped = False
        self.emergency = False
        self.target = 0.0
        self.last_seen_t = None
        self.silence = None  # watchdog: positive increments of t since the last feed
        self.feed_t = None
        self.jump_since_feed = False
        self.prev_t = None
        self.prev_u = 0.0
        self.down_ref = None  # (t, u) of the last update before the output had to ramp down
        self.rejections = {r.value: 0 for r in RejectionReason}
        self.updates = 0

    # ------------------------------------------------------------- model clock
    def _see(self, t: float) -> None:
        if self.last_seen_t is not None:
            if t > self.last_seen_t:
                if self.silence is not None:
                    self.silence += t - self.last_seen_t
            elif t < self.last_seen_t:
                self.jump_since_feed = True
        self.last_seen_t = t

    def _feed(self, t: float) -> None:
        # A feed stamped before the last update means t and the watchdog clock disagree.
        self.silence, self.feed_t = 0.0, t
        self.jump_since_feed = self.prev_t is not None and self.prev_t > t

    def _start_ramp_down(self) -> None:
        if self.down_ref is None:
            self.down_ref = (self.prev_t, self.prev_u)

    def _expected_state(self, output_V: float) -> ControllerState:
        if self.emergency:
            return ControllerState.EMERGENCY_STOP
        if self.tripped:
            return ControllerState.WATCHDOG_TRIPPED
        if self.activated:
            return ControllerState.ACTIVE
        return ControllerState.RAMPING_DOWN if output_V > 0.0 else ControllerState.INACTIVE

    # ------------------------------------------------------------- actions
    def command(self, value, t: float) -> None:
        self._see(t)
        target_before, state_before = self.c.target_V, self.c.state
        result = self.c.command(value, t)
        reason = _predicted_reason(value, self.limits.max_voltage_V, self.activated)
        if reason is None:
            assert result.accepted and result.reason == "accepted"
            self.target = float(value)
            self.tripped = False
            self._feed(t)
            self.down_ref = None
            assert self.c.target_V == self.target
            assert self.c.state is ControllerState.ACTIVE
        else:
            assert not result.accepted and result.reason == reason, (value, result)
            self.rejections[reason] += 1
            assert self.c.target_V == target_before, "a rejected command moved the target"
            assert self.c.state is state_before
        assert self.c.rejected_counts == self.rejections

    def activate(self, t: float) -> None:
        self._see(t)
        self.c.activate(t)
        if not self.activated:
            self.activated, self.tripped, self.emergency, self.target = True, False, False, 0.0
            self._feed(t)
            self.down_ref = None
        assert self.c.target_V == self.target
        assert self.c.state is self._expected_state(self.c.output_V)

    def deactivate(self, t: float) -> None:
        self._see(t)
        self.c.deactivate(t)
        self.target = 0.0
        if not self.emergency:
            if self.activated and not self.tripped:
                self._start_ramp_down()
            self.activated = self.tripped = False
        assert self.c.target_V == 0.0
        assert self.c.state is self._expected_state(self.c.output_V)

    def emergency_stop(self, t: float) -> None:
        self._see(t)
        if self.activated and not self.tripped:
            self._start_ramp_down()
        needed = self.c.emergency_ramp_down(t)
        assert needed == pytest.approx(self.c.output_V / self.limits.ramp_down_rate_V_per_s, rel=1e-12)
        self.emergency, self.activated, self.tripped, self.target = True, False, False, 0.0
        assert self.c.state is ControllerState.EMERGENCY_STOP and self.c.target_V == 0.0

    def update(self, t: float) -> None:
        lim = self.limits
        self._see(t)
        if self.activated and not self.tripped and self.silence > lim.watchdog_timeout_s:
            self.tripped, self.target = True, 0.0
            self._start_ramp_down()
            if not self.jump_since_feed and self.down_ref[0] is not None:
                # The trip is noticed at the first update after the deadline.
                deadline_t = self.feed_t + lim.watchdog_timeout_s
                assert self.down_ref[0] <= deadline_t + 1e-9 * (1.0 + abs(deadline_t))
        u = self.c.update(t)
        self.updates += 1
        state = self.c.state
        assert state is self._expected_state(u), (state, self._expected_state(u))
        assert self.c.target_V == self.target
        # Range.
        assert 0.0 <= u <= lim.max_voltage_V
        # Slew bound between consecutive updates; backward jumps do not move.
        if self.prev_t is not None:
            dt = t - self.prev_t
            if dt < 0.0:
                assert u == self.prev_u, "moved on a backward clock jump"
                dt = 0.0
            assert abs(u - self.prev_u) <= lim.slew_rate_V_per_s * dt * (1 + 1e-9) + 1e-300
            # Exact motion: toward the target at the slew rate, or to 0 V at the ramp rate.
            if state is ControllerState.ACTIVE:
                expected = _approach(self.prev_u, self.target, lim.slew_rate_V_per_s * dt)
            else:
                expected = _approach(self.prev_u, 0.0, lim.ramp_down_rate_V_per_s * dt)
                assert u <= self.prev_u, "output rose while not active"
            assert abs(u - expected) <= self.tol_V
        else:
            assert u == 0.0
        # Ramp-down deadline: zero by t_ref + u_ref / ramp, never above the ramp line.
        if state is not ControllerState.ACTIVE and self.down_ref is not None:
            if self.prev_t is not None and t < self.prev_t:
                self.down_ref = (t, u)  # the clock was re-based
            t_ref, u_ref = self.down_ref
            if t_ref is None:
                assert u == 0.0
            else:
                ramp_line = u_ref - lim.ramp_down_rate_V_per_s * (t - t_ref)
                assert u <= max(0.0, ramp_line) + self.tol_V
                if t - t_ref >= (u_ref / lim.ramp_down_rate_V_per_s) * (1 + 1e-9) + 1e-12:
                    assert u == 0.0, "not at 0 V after the ramp-down time"
        self.prev_t, self.prev_u = t, u

    # ------------------------------------------------------------- driver
    def run(self, n_events: int) -> None:
        rng, lim = self.rng, self.limits
        if rng.random() < 0.8:
            self.activate(self.t)
        for _ in range(n_events):
            r = rng.random()
            if r < 0.45:
                k = rng.random()
                if k < 0.10:
                    dt = 0.0
                elif k < 0.50:
                    dt = rng.uniform(0.0, 0.1 * lim.watchdog_timeout_s)
                elif k < 0.80:
                    dt = rng.uniform(0.0, lim.watchdog_timeout_s)
                elif k < 0.95:  # long silence, past the timeout and the ramp-down
                    dt = rng.uniform(lim.watchdog_timeout_s,
                                     3 * lim.watchdog_timeout_s + 2 * lim.max_voltage_V / lim.ramp_down_rate_V_per_s)
                elif k < 0.97:
                    dt = rng.uniform(1e6, 1e9)  # huge dt
                else:
                    dt = -rng.uniform(0.0, 10 * lim.watchdog_timeout_s)  # clock jumps back
                self.t += dt
                self.update(self.t)
            elif r < 0.83:
                if rng.random() < 0.15:
                    self.t -= rng.uniform(0.0, lim.watchdog_timeout_s)  # command stamped in the past
                else:
                    self.t += rng.uniform(0.0, 0.2 * lim.watchdog_timeout_s)
                burst = rng.randint(2, 25) if rng.random() < 0.2 else 1
                for _ in range(burst):  # bursts share one t
                    self.command(_random_value(rng, lim.max_voltage_V), self.t)
            elif r < 0.93:
                self.activate(self.t)
            elif r < 0.97:
                self.deactivate(self.t)
            elif r < 0.985:
                self.emergency_stop(self.t)
            else:
                diag = self.c.diagnostics()
                assert diag.rejected_counts == self.rejections
                assert diag.output_V == self.c.output_V and diag.state == self.c.state.value


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_fuzz_random_command_streams(seed):
    rng = random.Random(seed)
    total_updates = 0
    for _ in range(1000):
        checker = _FuzzChecker(rng)
        checker.run(rng.randint(20, 120))
        total_updates += checker.updates
    assert total_updates > 10_000  # the streams really exercised update()


def test_fuzz_watchdog_silence_reaches_zero_in_time():
    """Dedicated watchdog property: feed, go silent, sample at random times."""
    rng = np.random.default_rng(12345)
    for _ in range(2000):
        max_V = float(rng.uniform(10, 5000))
        slew = float(10 ** rng.uniform(0, 4))
        ramp = slew * float(rng.uniform(0.05, 1.0))
        timeout = float(rng.uniform(0.01, 2.0))
        controller = make(SafetyLimits(max_V, slew, timeout, ramp), active_at=0.0)
        t = 0.0
        for _ in range(int(rng.integers(1, 30))):  # random active phase, fed in time
            t += float(rng.uniform(0, timeout))
            controller.command(float(rng.uniform(0, max_V)), t)
            controller.update(t)
        deadline_t = t + timeout
        t_ref, u_ref = t, controller.output_V  # last update before the deadline
        previous_u = None
        for t in np.sort(rng.uniform(t, deadline_t + 2 * max_V / ramp + timeout, 40)):
            t = float(t)
            u = controller.update(t)
            if t <= deadline_t:
                assert controller.state is ControllerState.ACTIVE
                t_ref, u_ref = t, u
                continue
            assert controller.state is ControllerState.WATCHDOG_TRIPPED
            assert previous_u is None or u <= previous_u  # non-increasing after the timeout
            assert u <= max(0.0, u_ref - ramp * (t - t_ref)) + 1e-9 * max_V
            if t >= deadline_t + u_ref / ramp * (1 + 1e-9) + 1e-12:
                assert u == 0.0, "not at 0 V by timeout + output / ramp rate"
            previous_u = u


# =========================================================================== control clock
class TestControlClock:
    def test_forward_jumps_are_clamped_backward_jumps_add_nothing(self):
        clock = ControlClock(max_step_s=0.004)
        assert clock.advance(100.0, "sim") == 0.0  # first reading: reference only
        assert clock.advance(100.003, "sim") == pytest.approx(0.003)
        assert clock.advance(100.403, "sim") == pytest.approx(0.007)  # +0.4 s jump: one step of 4 ms
        assert clock.advance(50.0, "sim") == pytest.approx(0.007)  # backwards: nothing
        assert clock.advance(50.001, "sim") == pytest.approx(0.008)  # re-based on the new value
        assert clock.clamped_steps == 1 and clock.backward_steps == 1

    def test_sources_do_not_interfere(self):
        clock = ControlClock(max_step_s=0.01)
        clock.advance(1e9, "sim")
        clock.advance(5.0, "wall")
        assert clock.advance(5.005, "wall") == pytest.approx(0.005)
        assert clock.advance(1e9 + 100.0, "sim") == pytest.approx(0.015)  # stale source: one step at most
        clock.forget("wall")
        assert clock.advance(1e6, "wall") == pytest.approx(0.015)

    def test_slew_per_update_is_bounded_whatever_the_source_does(self):
        rng = random.Random(3)
        limits = SafetyLimits(3000.0, 1e5, 0.5, 1e4)
        period = 1e-3
        clock = ControlClock(max_step_s=period)
        controller = SafeVoltageController(limits)
        source = 0.0
        controller.activate(clock.advance(source))
        previous = controller.update(clock.now_s)
        for _ in range(20_000):
            source += rng.choice([period, -rng.uniform(0, 1e3), rng.uniform(0, 1e6), 0.0, 1e300])
            t = clock.advance(source)
            if rng.random() < 0.5:
                controller.command(rng.uniform(0, 3000.0), t)
            u = controller.update(t)
            assert abs(u - previous) <= 1e5 * period * (1 + 1e-12)
            previous = u

    def test_unlimited_clock_follows_its_source(self):
        clock = ControlClock()
        clock.advance(10.0)
        assert clock.advance(12.5) == 2.5
        with pytest.raises(SafetyConfigError, match="max_step_s"):
            ControlClock(max_step_s=0.0)
        with pytest.raises(ValueError):
            clock.advance(float("nan"))
