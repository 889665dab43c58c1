"""The ILD1320 laser sensor's behaviour without its port: settings, ASCII commands, measurement stream.

:class:`ILD1320Device` is what the sensor does with the bytes it receives and when it sends
which bytes; it never touches a port, and time is passed in (``time.monotonic()`` seconds;
only the additional ``TIMESTAMP`` value reads the clock).
:class:`~dea_ros.sim.ild1320_emulator.ILD1320Emulator` puts it on a pseudo-terminal.

* It answers the ASCII commands ``GETINFO``, ``MEASRATE [kHz]``, ``LASERPOW [FULL|OFF]``,
  ``OUTPUT [NONE|RS422|ANALOG]``, ``OUTADD_RS422 [NONE|<values>]``, ``OUTHOLD [NONE|0|<n>]``
  and ``MASTERMV [NONE|MASTER <mm>]`` with the reply format of
  :mod:`dea_ros.hardware.laser.ild1320_protocol` (body lines, CR LF, ``->``), and an ``Exxx``
  error for unknown commands or invalid parameters (the error numbers
  :data:`ERROR_UNKNOWN_COMMAND` etc. are this emulator's choice, not taken from the manual).
* It streams binary frames at the configured measuring rate: the sample ``k`` is acquired at
  ``t_k = t_0 + k / rate``, its value is ``displacement_source(t_k)`` (metres from the start
  of the measuring range), quantised to the sensor's digital resolution (values beyond the
  range reserves become the "too close"/"too far" error codes, NaN becomes "no peak", a
  :class:`~dea_ros.hardware.laser.base.MeasurementError` returned by the source is sent as its
  code), and it is output
  :data:`~dea_ros.hardware.laser.ild1320_protocol.frames.OUTPUT_DELAY_CYCLES` cycles after
  acquisition, like the sensor. Replies go out between frames, as the sensor keeps streaming
  while it answers.
* It keeps the settings a previous user may have left (constructor arguments, or set with the
  commands): ``mastering`` (the 18-bit shifted output of a mastered sensor, see
  :func:`~dea_ros.hardware.laser.ild1320_protocol.frames.mastered_displacement_to_code`),
  ``additional_outputs`` (values sent after each distance, H flags ``11``) and
  ``output_hold`` (an error value replaced by the last valid one).

The bytes the device sends go to :meth:`ILD1320Device._send`, which the transport provides.
The steps of the stream and of the command handling are methods of their own, so that a test
double can make the sensor misbehave (test/fakes/faulty_ild1320.py).
"""
from __future__ import annotations

import math
import threading
import time
from typing import Callable, Iterable, Sequence

from ..hardware.laser.base import MeasurementError
from ..hardware.laser.ild1320_protocol.commands import (
    ADDITIONAL_OUTPUTS,
    parse_command_line,
    render_error,
    render_reply,
    validate_measuring_rate_hz,
)
from ..hardware.laser.ild1320_protocol.frames import (
    DEFAULT_MEASURING_RANGE_M,
    ERROR_CODES,
    MAX_RAW_CODE,
    OUTPUT_DELAY_CYCLES,
    displacement_to_code,
    encode_value,
    mastered_displacement_to_code,
)

__all__ = [
    "ILD1320Device",
    "DisplacementSource",
    "mid_range_source",
    "positive_finite",
    "ERROR_UNKNOWN_COMMAND",
    "ERROR_WRONG_PARAMETER_COUNT",
    "ERROR_INVALID_PARAMETER",
    "ERROR_LINE_TOO_LONG",
    "ERROR_TIMEOUT",
]

#: ``displacement_source(t_s)``: displacement in metres from the start of the
#: measuring range at acquisition time ``t_s`` (``time.monotonic()`` seconds), or
#: a :class:`MeasurementError`, or NaN for "no target".
DisplacementSource = Callable[[float], float | MeasurementError]

#: Error replies (numbers chosen here; the manual's list was not found).
ERROR_UNKNOWN_COMMAND = (210, "Unknown command")
ERROR_WRONG_PARAMETER_COUNT = (220, "Wrong parameter count")
ERROR_INVALID_PARAMETER = (232, "Invalid parameter value")
ERROR_LINE_TOO_LONG = (214, "Entered command too long")
ERROR_TIMEOUT = (104, "Timeout")

_MAX_COMMAND_LINE_BYTES = 256


def positive_finite(name: str, value: float) -> float:
    """``value`` as a float; ``ValueError`` naming the setting unless it is positive and finite."""
    result = float(value)
    if not (math.isfinite(result) and result > 0.0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return result


def mid_range_source(measuring_range_m: float) -> DisplacementSource:
    """The default target: constant in the middle of the measuring range."""
    mid = 0.5 * measuring_range_m
    return lambda t_s: mid


class ILD1320Device:
    """The ILD1320's settings, command replies and measurement stream (see the module docstring).

    * ``displacement_source``: ``f(t_s) -> metres`` from the start of the measuring range
      (default: a constant mid-range target); called from the thread that streams;
    * ``measuring_rate_hz``: initial measuring rate, one of 250, 500, 1000, 2000 Hz;
    * ``measuring_range_m``: measuring range used for the quantisation (10 mm for the ILD1320-10);
    * ``serial_number``, ``model_name``: the ``GETINFO`` identity (default name
      ``ILD1320-<range in mm>``);
    * ``max_catch_up_s``: at most this much backlog of samples is sent after a stall (older
      samples are skipped, counted in ``samples_skipped_lag``);
    * ``mastering``: ``(master_position_m, master_value_m)``: the sensor is mastered as a
      previous user left it (``None``: not mastered);
    * ``additional_outputs``: additional values sent after each distance (``OUTADD_RS422``),
      e.g. ``("COUNTER",)``;
    * ``output_hold``: ``OUTHOLD`` mode: ``"NONE"`` (errors sent as errors), ``"0"`` (the last
      valid value is repeated instead of an error) or a number of cycles.
    """

    def __init__(
        self,
        displacement_source: DisplacementSource | None = None,
        *,
        measuring_rate_hz: float = 2000.0,
        measuring_range_m: float = DEFAULT_MEASURING_RANGE_M,
        serial_number: str = "00000000",
        max_catch_up_s: float = 0.5,
        mastering: tuple[float, float] | None = None,
        additional_outputs: Sequence[str] = (),
        output_hold: str = "NONE",
        model_name: str | None = None,
    ) -> None:
        self._range_m = positive_finite("measuring_range_m", measuring_range_m)
        self._source = displacement_source or mid_range_source(self._range_m)
        if not callable(self._source):
            raise TypeError(f"displacement_source must be callable, got {displacement_source!r}")
        self._rate_hz = validate_measuring_rate_hz(measuring_rate_hz)
        self._max_catch_up_s = positive_finite("max_catch_up_s", max_catch_up_s)
        self._serial_number = str(serial_number)
        self._model_name = model_name or f"ILD1320-{self._range_m * 1e3:g}"
        self._lock = threading.Lock()  # settings shared between the streaming thread and the API
        self._laser_on = True
        self._output = "RS422"
        self._mastering = self._check_mastering(mastering)
        self._additional = self._check_additional(additional_outputs)
        self._hold = self._check_hold(output_hold)
        self._last_valid_code: int | None = None
        self._held_cycles = 0
        self._segment_t0 = 0.0  # acquisition time of sample 0 at the present rate
        self._segment_next = 0  # next sample index at the present rate
        self._next_index = 0  # running number of the frames sent
        self._line = bytearray()  # command bytes received, not yet a line
        self.frames_emitted = 0
        self.samples_not_output = 0
        self.samples_skipped_lag = 0
        self.additional_values_emitted = 0
        self.commands_received = 0
        self.source_errors = 0
        self.last_source_error: BaseException | None = None

    # ------------------------------------------------------------------ settings
    @property
    def measuring_rate_hz(self) -> float:
        with self._lock:
            return self._rate_hz

    @property
    def measuring_range_m(self) -> float:
        return self._range_m

    @property
    def laser_on(self) -> bool:
        with self._lock:
            return self._laser_on

    @property
    def output_channel(self) -> str:
        with self._lock:
            return self._output

    @property
    def mastering(self) -> tuple[float, float] | None:
        """``(master_position_m, master_value_m)`` while mastered, else ``None``."""
        with self._lock:
            return self._mastering

    @property
    def additional_outputs(self) -> tuple[str, ...]:
        with self._lock:
            return self._additional

    @property
    def output_hold(self) -> str:
        with self._lock:
            return self._hold

    def _check_mastering(self, mastering: tuple[float, float] | None) -> tuple[float, float] | None:
        if mastering is None:
            return None
        position, value = (float(v) for v in mastering)
        if not (math.isfinite(position) and 0.0 <= position <= self._range_m):
            raise ValueError(f"master position must be in [0, {self._range_m}] m, got {position!r}")
        if not (math.isfinite(value) and 0.0 <= value <= 2.0 * self._range_m):
            raise ValueError(f"master value must be in [0, 2 MR] = [0, {2 * self._range_m}] m, got {value!r}")
        return (position, value)

    @staticmethod
    def _check_additional(values: Iterable[str]) -> tuple[str, ...]:
        names = tuple(str(v).upper() for v in values)
        for name in names:
            if name not in ADDITIONAL_OUTPUTS:
                raise ValueError(f"additional output must be one of {ADDITIONAL_OUTPUTS}, got {name!r}")
        return tuple(n for n in ADDITIONAL_OUTPUTS if n in names)  # output order

    @staticmethod
    def _check_hold(mode: str) -> str:
        text = str(mode).strip().upper()
        if text != "NONE" and not text.isdigit():
            raise ValueError(f"output_hold must be NONE, 0 or a number of cycles, got {mode!r}")
        return text if text == "NONE" else str(int(text))

    # ------------------------------------------------------------------ the serial line
    def _send(self, data: bytes) -> None:
        """Put ``data`` on the sensor's serial output (the transport provides it)."""
        raise NotImplementedError

    def _restart_stream(self, now: float) -> None:
        """Sample 0 of the stream is acquired at ``now`` (power-up)."""
        with self._lock:
            self._segment_t0 = now
            self._segment_next = 0

    def _receive(self, data: bytes, now: float) -> None:
        """Bytes arrived on the sensor's serial input at ``now``: answer every complete command line."""
        self._line += data
        while True:
            newline = self._line.find(b"\n")
            if newline < 0:
                if len(self._line) > _MAX_COMMAND_LINE_BYTES:
                    self._line.clear()
                    self._emit_due(now)
                    self._send(render_error(*ERROR_LINE_TOO_LONG))
                return
            raw_line = bytes(self._line[:newline]).strip(b"\r \t")
            del self._line[: newline + 1]
            if not raw_line:
                continue
            self.commands_received += 1
            reply = self._execute(raw_line, now)
            self._emit_due(now)  # frames due before the reply go first
            self._send(reply)

    # ------------------------------------------------------------------ commands
    def _execute(self, raw_line: bytes, now: float) -> bytes:
        """The reply to one command line."""
        try:
            name, params = parse_command_line(raw_line.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            return render_error(*ERROR_INVALID_PARAMETER)
        return self._reply(name, params, now)

    def _reply(self, name: str, params: list[str], now: float) -> bytes:
        """The reply to the command ``name`` with ``params`` (upper-case name)."""
        handlers: dict[str, Callable[[list[str], float], bytes]] = {
            "GETINFO": self._cmd_getinfo,
            "MEASRATE": self._cmd_measrate,
            "LASERPOW": self._cmd_laserpow,
            "OUTPUT": self._cmd_output,
            "OUTADD_RS422": self._cmd_outadd,
            "OUTHOLD": self._cmd_outhold,
            "MASTERMV": self._cmd_mastermv,
        }
        handler = handlers.get(name)
        if handler is None:
            return render_error(*ERROR_UNKNOWN_COMMAND)
        return handler(params, now)

    def _info_lines(self, model: str, range_mm: float) -> list[str]:
        """The ``GETINFO`` reply's lines for a sensor ``model`` with a measuring range of ``range_mm``."""
        return [
            f"Name:            {model}",
            f"Serial:          {self._serial_number}",
            "Option:          000",
            "Article:         0000000",
            "Cable head:      Wire",
            f"Measuring range: {range_mm:.2f}mm",
            "Version:         emulator",
            "Hardware-rev:    00",
            "Boot-version:    emulator",
        ]

    def _cmd_getinfo(self, params: list[str], now: float) -> bytes:
        if params:
            return render_error(*ERROR_WRONG_PARAMETER_COUNT)
        return render_reply(self._info_lines(self._model_name, self._range_m * 1e3))

    def _cmd_outadd(self, params: list[str], now: float) -> bytes:
        with self._lock:
            if not params:
                return render_reply([f"OUTADD_RS422 {' '.join(self._additional) or 'NONE'}"])
            names = [p.upper() for p in params]
            if names == ["NONE"]:
                self._additional = ()
                return render_reply()
            try:
                self._additional = self._check_additional(names)
            except ValueError:
                return render_error(*ERROR_INVALID_PARAMETER)
        return render_reply()

    def _cmd_outhold(self, params: list[str], now: float) -> bytes:
        if len(params) > 1:
            return render_error(*ERROR_WRONG_PARAMETER_COUNT)
        with self._lock:
            if not params:
                return render_reply([f"OUTHOLD {self._hold}"])
            try:
                self._hold = self._check_hold(params[0])
            except ValueError:
                return render_error(*ERROR_INVALID_PARAMETER)
            self._held_cycles = 0
        return render_reply()

    def _cmd_mastermv(self, params: list[str], now: float) -> bytes:
        with self._lock:
            if not params:
                if self._mastering is None:
                    return render_reply(["MASTERMV NONE"])
                return render_reply([f"MASTERMV MASTER {self._mastering[1] * 1e3:.6f}"])
            choice = params[0].upper()
            if choice == "NONE" and len(params) == 1:
                self._mastering = None
                self._last_valid_code = None
                return render_reply()
        if choice != "MASTER" or len(params) != 2:
            return render_error(*ERROR_WRONG_PARAMETER_COUNT if choice == "MASTER" else ERROR_INVALID_PARAMETER)
        try:
            master_value_m = float(params[1]) * 1e-3
        except ValueError:
            return render_error(*ERROR_INVALID_PARAMETER)
        try:
            position = self._source(now)
        except Exception:  # noqa: BLE001 - a faulty source is "no measurement value"
            position = math.nan
        if isinstance(position, MeasurementError) or not (
            math.isfinite(float(position)) and 0.0 <= float(position) <= self._range_m
        ):
            return render_error(*ERROR_TIMEOUT)  # no valid value to master within the timeout
        try:
            mastering = self._check_mastering((float(position), master_value_m))
        except ValueError:
            return render_error(*ERROR_INVALID_PARAMETER)
        with self._lock:
            self._mastering = mastering
            self._last_valid_code = None
        return render_reply()

    def _cmd_measrate(self, params: list[str], now: float) -> bytes:
        if not params:
            with self._lock:
                return render_reply([f"MEASRATE {self._rate_hz / 1000.0:g}"])
        if len(params) != 1:
            return render_error(*ERROR_WRONG_PARAMETER_COUNT)
        try:
            rate_hz = validate_measuring_rate_hz(float(params[0]) * 1000.0)
        except ValueError:
            return render_error(*ERROR_INVALID_PARAMETER)
        self._emit_due(now)  # samples of the old rate that are due are still sent
        with self._lock:
            if rate_hz != self._rate_hz:
                self._rate_hz = rate_hz
                self._segment_t0 = now
                self._segment_next = 0
        return render_reply()

    def _cmd_laserpow(self, params: list[str], now: float) -> bytes:
        if len(params) > 1:
            return render_error(*ERROR_WRONG_PARAMETER_COUNT)
        with self._lock:
            if not params:
                return render_reply([f"LASERPOW {'FULL' if self._laser_on else 'OFF'}"])
            choice = params[0].upper()
            if choice not in ("FULL", "OFF"):
                return render_error(*ERROR_INVALID_PARAMETER)
            self._laser_on = choice == "FULL"
        return render_reply()

    def _cmd_output(self, params: list[str], now: float) -> bytes:
        if len(params) > 1:
            return render_error(*ERROR_WRONG_PARAMETER_COUNT)
        with self._lock:
            if not params:
                return render_reply([f"OUTPUT {self._output}"])
            choice = params[0].upper()
            if choice not in ("NONE", "RS422", "ANALOG"):
                return render_error(*ERROR_INVALID_PARAMETER)
            self._output = choice
        return render_reply()

    # ------------------------------------------------------------------ the stream
    def _emit_due(self, now: float) -> None:
        """Send every sample output by ``now`` (acquired ``OUTPUT_DELAY_CYCLES`` cycles before)."""
        with self._lock:
            rate = self._rate_hz
            period = 1.0 / rate
            delay = OUTPUT_DELAY_CYCLES * period
            laser_on = self._laser_on
            streaming = self._output == "RS422"
            end = math.floor((now - delay - self._segment_t0) * rate) + 1
            first = self._segment_next
            if end - first > self._max_catch_up_s * rate:
                skipped = end - first - int(self._max_catch_up_s * rate)
                self.samples_skipped_lag += skipped
                first += skipped
            self._segment_next = max(end, self._segment_next)
            segment_t0 = self._segment_t0
        for n in range(first, end):
            t_acq = segment_t0 + n * period
            self._output_sample(t_acq, t_acq + delay, laser_on, streaming)

    def _output_sample(self, t_acq: float, t_out: float, laser_on: bool, streaming: bool) -> None:
        """The sample acquired at ``t_acq``, due at ``t_out``: sent, or counted while the output is off."""
        if not streaming:
            self.samples_not_output += 1
            return
        self._send_sample(t_acq, self._sample_code(t_acq, laser_on))

    def _send_sample(self, t_acq: float, code: int) -> None:
        """Send the frame of ``code`` and its additional values."""
        self._send(encode_value(code) + self._additional_frames(code))
        self.frames_emitted += 1
        self._next_index += 1

    def _sample_code(self, t_acq: float, laser_on: bool) -> int:
        """The code sent for the sample acquired at ``t_acq`` (quantised, mastered, held)."""
        if not laser_on:
            code = displacement_to_code(MeasurementError.LASER_OFF, self._range_m)
        else:
            with self._lock:
                mastering = self._mastering
            try:
                value = self._source(t_acq)
                if mastering is None:
                    code = displacement_to_code(value, self._range_m)
                else:
                    code = mastered_displacement_to_code(value, mastering[0], mastering[1], self._range_m)
            except Exception as exc:  # a faulty model must not kill the sensor
                self.source_errors += 1
                self.last_source_error = exc
                code = displacement_to_code(MeasurementError.CANNOT_CALCULATE, self._range_m)
        return self._apply_hold(code)

    def _apply_hold(self, code: int) -> int:
        with self._lock:
            hold = self._hold
            if code not in ERROR_CODES:
                self._last_valid_code = code
                self._held_cycles = 0
                return code
            if hold == "NONE" or self._last_valid_code is None:
                return code
            if hold != "0" and self._held_cycles >= int(hold):
                return code
            self._held_cycles += 1
            return self._last_valid_code

    def _additional_frames(self, code: int) -> bytes:
        """The additional values (``OUTADD_RS422``) sent after the frame of ``code``."""
        with self._lock:
            names = self._additional
        if not names:
            return b""
        out = bytearray()
        for name in names:
            for value in self._additional_values(name, code):
                out += encode_value(value, additional=True)
                self.additional_values_emitted += 1
        return bytes(out)

    def _additional_values(self, name: str, code: int) -> list[int]:
        if name == "COUNTER":
            return [self._next_index & MAX_RAW_CODE]
        if name == "SHUTTER":
            return [1000]  # 100.0 us exposure
        if name == "TIMESTAMP":  # two 16-bit words, 10 us units
            ticks = int(time.monotonic() * 1e5) & 0xFFFFFFFF
            return [ticks & 0xFFFF, ticks >> 16]
        if name == "INTENSITY":
            return [32736]  # 50 %
        if name == "STATE":
            return [0]
        return [code]  # DIST_RAW
