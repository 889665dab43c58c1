"""Micro-Epsilon ILD1320 backend over a serial port (pyserial).

:class:`ILD1320Sensor` implements :class:`~dea_ros.hardware.laser.base.DisplacementSensor`
for the optoNCDT 1320 on an RS422/USB adapter (or on the pty of
:class:`~dea_ros.sim.ild1320_emulator.ILD1320Emulator`). Protocol details
are in :mod:`dea_ros.hardware.laser.ild1320_protocol`. pyserial is imported with this
module: its users import it when a serial sensor is used.

Reading: all bytes waiting are read at every :meth:`~ILD1320Sensor.read_batch` (and while waiting
for replies), decoded by a :class:`~dea_ros.hardware.laser.ild1320_protocol.frames.FrameDecoder`
(which also keeps the interleaved ASCII replies), stamped by a
:class:`~dea_ros.hardware.laser.sample_clock.SampleClock` (the sensor sends no time stamps),
checked by a :class:`~dea_ros.hardware.laser.plausibility.PlausibilityFilter` (the frame has no
checksum; a discarded sample is returned as a reading whose value is the reason) and queued.

Connecting (:meth:`ILD1320Sensor.open`): resynchronise (flush, stop the stream, read until a
complete reply and a quiet line, within ``resync_timeout_s``: a sensor streams from power-on and
the port may hold partial frames), read what the sensor reports (``GETINFO``, ``MEASRATE``,
``OUTPUT``, ``OUTADD_RS422``, ``OUTHOLD``, ``MASTERMV``) and compare it with the configuration
(:func:`~dea_ros.hardware.laser.ild1320_protocol.settings.check_laser_sensor`; another model,
range or a non-ILD1320 rate raise :class:`~dea_ros.errors.SensorConfigurationError`), set the
known state (``OUTADD_RS422 NONE``, ``OUTHOLD NONE``, ``MASTERMV NONE``, ``MEASRATE``, then
``OUTPUT RS422``) and read every setting back; the ``OUTPUT_DELAY_CYCLES`` + 1 samples after it
are dropped. :func:`describe_ild1320` reads and checks, and leaves the sensor as it was.

Disconnects: a serial exception closes the port and raises
:class:`~dea_ros.errors.SensorDisconnected`; so does silence (no valid frame for
``no_data_timeout_periods`` sample periods, at least ``min_no_data_timeout_s``), from which the
backend recovers by itself when frames arrive again; after a serial error call
:meth:`ILD1320Sensor.reconnect` (retries with exponential backoff).
"""
from __future__ import annotations

import collections
import dataclasses
import math
import select
import time
from typing import Any, Callable

import serial

from ...errors import CommandError, SensorConfigurationError, SensorDisconnected, SensorError
from .base import (DisplacementReading, DisplacementSensor, MeasurementError, validated_positive,
                   validated_tare_offset_m)
from .ild1320_protocol.commands import (
    CommandReply,
    SensorInfo,
    command_bytes,
    find_reply_end,
    getinfo_command,
    laser_command,
    mastermv_command,
    measrate_command,
    outadd_rs422_command,
    outhold_command,
    output_command,
    parse_getinfo_reply,
    parse_laser_reply,
    parse_mastermv_reply,
    parse_measrate_reply,
    parse_measrate_value_hz,
    parse_outadd_rs422_reply,
    parse_outhold_reply,
    parse_output_reply,
    parse_reply,
    validate_measuring_rate_hz,
)
from .ild1320_protocol.frames import (
    BYTES_PER_VALUE,
    DEFAULT_BAUDRATE,
    DEFAULT_MEASURING_RANGE_M,
    OUTPUT_DELAY_CYCLES,
    SERIAL_BYTESIZE,
    SERIAL_PARITY,
    SERIAL_STOPBITS,
    FrameDecoder,
)
from .ild1320_protocol.settings import (
    KNOWN_STATE,
    LaserSensorExpectation,
    LaserSensorReport,
    LaserSensorSettings,
    check_laser_sensor,
)
from .plausibility import (
    DEFAULT_CONFIRM_SAMPLES,
    DEFAULT_JUMP_TOLERANCE_M,
    DEFAULT_MAX_SPEED_M_PER_S,
    PlausibilityFilter,
)
from .sample_clock import SampleClock

__all__ = ["ILD1320Sensor", "describe_ild1320"]

_READ_CHUNK_BYTES = 65536
_BITS_PER_BYTE_8N1 = 10


class ILD1320Sensor(DisplacementSensor):
    """ILD1320 on a serial port; see the module docstring.

    * ``port``: serial device (``/dev/ttyUSB0``, the emulator's pty or its symlink);
    * ``baudrate``: 921600 (factory setting); 8N1 framing is fixed;
    * ``timeout_s``: reply timeout of each ASCII command and write timeout, s;
    * ``measuring_range_m``: measuring range of the head the configuration expects (10 mm
      for the ILD1320-10): :meth:`open` refuses a sensor whose ``GETINFO`` reports another
      one (:class:`SensorConfigurationError`); ``None`` accepts the reported range (it must
      be present and consistent with the model name);
    * ``measuring_rate_hz``: rate to set on every :meth:`open` (``None``: keep the sensor's
      setting, which must be an ILD1320 rate); read back and checked;
    * ``enable_rs422_output``: send ``OUTPUT RS422`` on :meth:`open` so that values are streamed;
    * ``max_speed_m_per_s``, ``jump_tolerance_m``, ``confirm_samples``, ``max_acceleration_m_per_s2``:
      of :class:`PlausibilityFilter` (a discarded sample's decoded value is the reading's ``raw_m``);
    * ``no_data_timeout_periods``, ``min_no_data_timeout_s``: silence longer than
      ``max(periods / rate, min)`` means disconnected;
    * ``resync_timeout_s``: bound of the resynchronisation at every :meth:`open` (see
      :meth:`_resynchronise`);
    * ``serial_factory``: replaces ``serial.Serial`` (keyword arguments as pyserial's).
    """

    def __init__(
        self,
        port: str,
        baudrate: int = DEFAULT_BAUDRATE,
        timeout_s: float = 0.5,
        *,
        measuring_range_m: float | None = None,
        measuring_rate_hz: float | None = None,
        enable_rs422_output: bool = True,
        no_data_timeout_periods: int = 200,
        min_no_data_timeout_s: float = 0.3,
        max_queued_samples: int = 100_000,
        serial_factory: Callable[..., Any] | None = None,
        max_speed_m_per_s: float = DEFAULT_MAX_SPEED_M_PER_S,
        jump_tolerance_m: float = DEFAULT_JUMP_TOLERANCE_M,
        confirm_samples: int = DEFAULT_CONFIRM_SAMPLES,
        resync_timeout_s: float = 3.0,
        max_acceleration_m_per_s2: float | None = None,
    ) -> None:
        self._port = str(port)
        self._baudrate = int(validated_positive("baudrate", baudrate))
        self._timeout_s = validated_positive("timeout_s", timeout_s)
        self._resync_timeout_s = validated_positive("resync_timeout_s", resync_timeout_s)
        self._range_override_m = (None if measuring_range_m is None
                                  else validated_positive("measuring_range_m", measuring_range_m))
        self._requested_rate_hz = None if measuring_rate_hz is None else validate_measuring_rate_hz(measuring_rate_hz)
        self._enable_output = bool(enable_rs422_output)
        self._no_data_periods = int(no_data_timeout_periods)
        if self._no_data_periods < 1:
            raise ValueError(f"no_data_timeout_periods must be >= 1, got {no_data_timeout_periods!r}")
        self._min_no_data_s = validated_positive("min_no_data_timeout_s", min_no_data_timeout_s)
        self._serial_factory = serial_factory or serial.Serial

        self._serial: Any | None = None
        self._lost = False  # port closed because of an I/O error
        self._rate_hz = self._requested_rate_hz or 2000.0
        self._info: SensorInfo | None = None
        self._decoder = FrameDecoder(
            self._range_override_m or DEFAULT_MEASURING_RANGE_M, keep_non_frame_bytes=True
        )
        self._clock = SampleClock(self._rate_hz, self._latency_s(self._rate_hz))
        self._filter = PlausibilityFilter(
            self._decoder.measuring_range_m,
            max_speed_m_per_s=max_speed_m_per_s,
            jump_tolerance_m=jump_tolerance_m,
            confirm_samples=confirm_samples, max_acceleration_m_per_s2=max_acceleration_m_per_s2)
        self._configuring = False
        self._settle_remaining = 0
        self._connect_report: LaserSensorReport | None = None
        self._queue: collections.deque[tuple[float, float | MeasurementError, float]] = collections.deque()
        self._max_queued = int(max_queued_samples)
        if self._max_queued < 1:
            raise ValueError(f"max_queued_samples must be >= 1, got {max_queued_samples!r}")
        self._recent_valid_m: collections.deque[float] = collections.deque(maxlen=10_000)
        self._valid_count = 0
        self._tare_m = 0.0
        self._last_frame_time = -math.inf
        self.samples_dropped_queue_full = 0
        self.samples_ignored_while_configuring = 0

    # ------------------------------------------------------------------ properties
    @property
    def port(self) -> str:
        return self._port

    @property
    def decoder(self) -> FrameDecoder:
        """The frame decoder (its counters tell about stream corruption)."""
        return self._decoder

    @property
    def sample_clock(self) -> SampleClock:
        return self._clock

    @property
    def plausibility_filter(self) -> PlausibilityFilter:
        return self._filter

    @property
    def connect_report(self) -> LaserSensorReport | None:
        """What the sensor reported at the last :meth:`open`, before it was reset (``None``: not read)."""
        return self._connect_report

    def diagnostic_counters(self) -> dict[str, int]:
        """Cumulative byte/frame counters (discards per reason come as error readings)."""
        d = self._decoder
        return {
            "frames_decoded": d.frames_decoded,
            "bytes_discarded": d.bytes_discarded,
            "partial_frames_dropped": d.partial_frames_dropped,
            "additional_values_skipped": d.additional_values_skipped,
            "samples_lost_estimate": self._clock.periods_skipped,
            "samples_dropped_queue_full": self.samples_dropped_queue_full,
            "samples_ignored_while_configuring": self.samples_ignored_while_configuring,
            "plausibility_reanchors": self._filter.reanchors,
        }

    @property
    def measuring_range_m(self) -> float:
        return self._decoder.measuring_range_m

    @property
    def tare_offset_m(self) -> float:
        return self._tare_m

    @property
    def no_data_timeout_s(self) -> float:
        """Silence (s) after which the sensor counts as disconnected."""
        return max(self._min_no_data_s, self._no_data_periods / self._rate_hz)

    def _latency_s(self, rate_hz: float) -> float:
        return OUTPUT_DELAY_CYCLES / rate_hz + BYTES_PER_VALUE * _BITS_PER_BYTE_8N1 / self._baudrate

    # ------------------------------------------------------------------ lifecycle
    def _expectation(self) -> LaserSensorExpectation:
        return LaserSensorExpectation(self._range_override_m, self._requested_rate_hz)

    def _open_port(self) -> None:
        if self._serial is not None:
            raise SensorError(f"ILD1320 on {self._port} is already open")
        try:
            port = self._serial_factory(
                port=self._port,
                baudrate=self._baudrate,
                bytesize=SERIAL_BYTESIZE,
                parity=SERIAL_PARITY,
                stopbits=SERIAL_STOPBITS,
                timeout=0,
                write_timeout=self._timeout_s,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise SensorDisconnected(f"cannot open ILD1320 serial port {self._port!r}: {exc}") from exc
        self._serial = port
        self._lost = False
        self._decoder.reset()
        self._queue.clear()
        self._clock.reset(self._rate_hz, self._latency_s(self._rate_hz))
        self._last_frame_time = time.monotonic()

    def open(self) -> None:
        """Open the port, check the sensor against the configuration, set the known state.

        Raises :class:`SensorDisconnected` if the port cannot be opened or the
        sensor does not answer, :class:`SensorConfigurationError` when the sensor
        differs from the configuration (see :attr:`connect_report`),
        :class:`SensorError` for refused commands, bad replies or settings that do
        not read back as set. The port is closed again on any failure.
        """
        self._open_port()
        self._configuring = True
        try:
            output = self._resynchronise()
            settings = dataclasses.replace(self.read_settings(), output=output)
            report = check_laser_sensor(settings, self._expectation())
            self._connect_report = report
            if not report.ok:
                raise SensorConfigurationError(
                    f"ILD1320 on {self._port} does not match the configuration: " + "; ".join(report.mismatches),
                    report.mismatches,
                )
            assert settings.measuring_range_m is not None  # checked above
            self._decoder.measuring_range_m = settings.measuring_range_m
            self._filter.measuring_range_m = settings.measuring_range_m
            self._apply_known_state()
        except (serial.SerialException, OSError) as exc:
            self._close_port()
            raise SensorDisconnected(f"I/O error while configuring ILD1320 on {self._port}: {exc}") from exc
        except BaseException:
            self._close_port()
            raise
        finally:
            self._configuring = False
        self._queue.clear()
        self._filter.reset()
        self._settle_remaining = OUTPUT_DELAY_CYCLES + 1

    def _resynchronise(self) -> str | None:
        """Flush, stop the stream, drop bytes until quiet: the output channel it had (``None``: unreadable).

        ``OUTPUT NONE`` is repeated until a complete reply acknowledges it (replies resynchronise
        on their start: ``commands.resync_first_line``), all within ``resync_timeout_s``.
        """
        self._serial.reset_input_buffer()
        deadline = time.monotonic() + self._resync_timeout_s
        output = self._ask(output_command(None), parse_output_reply, deadline, required=False)
        self._ask(output_command("NONE"), lambda reply: reply, deadline)
        quiet_s = max(4.0 / self._rate_hz, 0.02)
        while time.monotonic() < deadline:
            self._wait_readable(quiet_s)
            if not self._serial.read(_READ_CHUNK_BYTES):
                break
        self._decoder.reset()
        self._clock.reset(self._rate_hz, self._latency_s(self._rate_hz))  # the backlog's stamps mean nothing
        return output

    def _ask(self, command: str, parse: Callable[[CommandReply], Any], deadline: float,
             required: bool = True) -> Any:
        """``parse`` of the reply to ``command``, repeated until it parses or ``deadline`` (monotonic s);
        not repeated when refused (``Exxx``); ``required=False``: ``None`` then (silence raises)."""
        while True:
            try:
                return parse(self._command(command))
            except CommandError:
                if required:
                    raise
                return None
            except SensorError:
                if time.monotonic() < deadline:
                    continue
                if required:
                    raise
                return None

    def _query(self, command: str, parse: Callable[[CommandReply], Any], unreadable: list[str]) -> Any:
        """A query whose failure (refused, unparsable) is recorded, not raised; silence still raises."""
        try:
            return self._ask(command, parse, time.monotonic() + self._timeout_s)
        except SensorDisconnected:
            raise
        except SensorError as exc:
            unreadable.append(f"{command}: {exc}")
            return None

    def read_settings(self) -> LaserSensorSettings:
        """Query identity and settings without changing anything (port must be open).

        ``GETINFO`` must answer (else :class:`SensorError`); other queries that
        fail are listed in ``unreadable``.
        """
        info = self.info()
        unreadable: list[str] = []
        return LaserSensorSettings(
            model=info.name,
            serial_number=info.serial,
            measuring_range_m=info.measuring_range_m,
            measuring_rate_hz=self._query(measrate_command(), parse_measrate_value_hz, unreadable),
            output=self._query(output_command(None), parse_output_reply, unreadable),
            additional_outputs=self._query(outadd_rs422_command(None), parse_outadd_rs422_reply, unreadable),
            output_hold=self._query(outhold_command(None), parse_outhold_reply, unreadable),
            mastering=self._query(mastermv_command(reset=False), parse_mastermv_reply, unreadable),
            unreadable=tuple(unreadable),
        )

    def describe(self) -> LaserSensorReport:
        """Read the sensor's current settings and compare them with the configuration."""
        self._require_port()
        return check_laser_sensor(self.read_settings(), self._expectation())

    def _apply_known_state(self) -> None:
        self._command(outadd_rs422_command(()))
        self._command(outhold_command("NONE"))
        self._command(mastermv_command(reset=True))
        if self._requested_rate_hz is not None:
            self._command(measrate_command(self._requested_rate_hz))
        if self._enable_output:  # the stream is restarted last: the settings went over a quiet line
            self._command(output_command("RS422"))
        # read everything back: a sensor that acknowledges and keeps a setting is refused
        problems = []
        rate = self.measuring_rate()  # validated: an unsupported rate raises
        if self._requested_rate_hz is not None and not math.isclose(rate, self._requested_rate_hz):
            problems.append(f"measuring rate {rate:g} Hz after MEASRATE {self._requested_rate_hz / 1000.0:g}")
        checks = [
            (outadd_rs422_command(None), parse_outadd_rs422_reply, KNOWN_STATE["additional_outputs"]),
            (outhold_command(None), parse_outhold_reply, KNOWN_STATE["output_hold"]),
            (mastermv_command(reset=False), parse_mastermv_reply, KNOWN_STATE["mastering"]),
        ]
        if self._enable_output:
            checks.insert(0, (output_command(None), parse_output_reply, KNOWN_STATE["output"]))
        for command, parse, wanted in checks:
            got = parse(self._command(command))
            if got != wanted:
                shown = " ".join(got) if isinstance(got, tuple) else got
                problems.append(f"{command} reads back {shown or 'NONE'!r} after setting it to "
                                f"{(' '.join(wanted) if isinstance(wanted, tuple) else wanted) or 'NONE'!r}")
        if problems:
            raise SensorError(f"ILD1320 on {self._port} did not take the known state: " + "; ".join(problems))

    def close(self) -> None:
        self._close_port()
        self._lost = False
        self._queue.clear()

    def _close_port(self) -> None:
        port, self._serial = self._serial, None
        if port is not None:
            try:
                port.close()
            except Exception:
                pass

    def _require_port(self) -> Any:
        if self._serial is None:
            if self._lost:
                raise SensorDisconnected(
                    f"ILD1320 port {self._port} was closed after an I/O error; call reconnect()"
                )
            raise SensorError(f"ILD1320 on {self._port} is not open")
        return self._serial

    def _io_error(self, exc: BaseException) -> SensorDisconnected:
        self._close_port()
        self._lost = True
        return SensorDisconnected(f"ILD1320 serial port {self._port} failed: {exc}")

    def is_connected(self) -> bool:
        return (
            self._serial is not None
            and time.monotonic() - self._last_frame_time <= self.no_data_timeout_s
        )

    def reconnect(
        self,
        timeout_s: float = 5.0,
        initial_backoff_s: float = 0.05,
        max_backoff_s: float = 1.0,
    ) -> None:
        """Close and re-open until frames flow again, with exponential backoff.

        Keeps the tare and the requested measuring rate. Raises
        :class:`SensorDisconnected` if not connected within ``timeout_s``, and
        :class:`SensorConfigurationError` at once when the sensor now connected
        differs from the configuration (retrying cannot help).
        """
        deadline = time.monotonic() + float(timeout_s)
        backoff = float(initial_backoff_s)
        if not (backoff > 0.0 and float(max_backoff_s) >= backoff):
            raise ValueError("need 0 < initial_backoff_s <= max_backoff_s")
        attempts = 0
        last_error: BaseException | None = None
        while True:
            attempts += 1
            self._close_port()
            try:
                self.open()
                if self._wait_for_frames(min(max(deadline - time.monotonic(), 0.0), self.no_data_timeout_s)):
                    return
                raise SensorDisconnected(f"ILD1320 on {self._port} opened but sends no data")
            except SensorConfigurationError:
                self._close_port()
                raise
            except SensorError as exc:
                last_error = exc
                self._close_port()
                self._lost = True
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                raise SensorDisconnected(
                    f"could not reconnect to ILD1320 on {self._port} within {timeout_s} s "
                    f"({attempts} attempts); last error: {last_error}"
                ) from last_error
            time.sleep(min(backoff, remaining))
            backoff = min(2.0 * backoff, float(max_backoff_s))

    # ------------------------------------------------------------------ reading
    def _wait_readable(self, timeout_s: float) -> None:
        port = self._serial
        if port is None or timeout_s <= 0.0:
            return
        try:
            select.select([port.fileno()], [], [], timeout_s)
        except (AttributeError, TypeError, ValueError, OSError):
            time.sleep(min(timeout_s, 0.001))

    def _pump(self) -> int:
        """Read and decode everything available; returns the number of new samples."""
        port = self._require_port()
        new_samples = 0
        try:
            while True:
                waiting = port.in_waiting
                data = port.read(min(max(waiting, 1), _READ_CHUNK_BYTES))
                arrival = time.monotonic()
                if not data:
                    break
                new_samples += self._ingest(data, arrival)
                if len(data) < _READ_CHUNK_BYTES:
                    break
        except (serial.SerialException, OSError) as exc:
            raise self._io_error(exc) from exc
        return new_samples

    def _ingest(self, data: bytes, arrival_time_s: float) -> int:
        samples = self._decoder.feed(data)
        if not samples:
            return 0
        if self._configuring:  # a backlog arrives in a burst: stamping it would run the clock ahead
            self._last_frame_time = arrival_time_s
            self.samples_ignored_while_configuring += len(samples)
            return 0
        times = self._clock.stamp(
            len(samples),
            arrival_time_s,
            loss_before=[sample.discarded_before > 0 for sample in samples],
            loss_after=self._decoder.discarded_since_last_frame > 0,
        )
        self._last_frame_time = arrival_time_s
        queued = 0
        for t_s, sample in zip(times, samples):
            if self._settle_remaining > 0:  # acquired while the known state was set (maybe mastered)
                self._settle_remaining -= 1
                self.samples_ignored_while_configuring += 1
                continue
            value = self._filter.check(t_s, sample.value, sample.discarded_before > 0)
            if len(self._queue) >= self._max_queued:
                self._queue.popleft()
                self.samples_dropped_queue_full += 1
            self._queue.append((t_s, value, sample.value if isinstance(value, MeasurementError)
                                and not isinstance(sample.value, MeasurementError) else math.nan))
            queued += 1
            if not isinstance(value, MeasurementError):
                self._recent_valid_m.append(value)
                self._valid_count += 1
        return queued

    def _wait_for_frames(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while True:
            if self._pump() > 0 or self._queue:
                return True
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                return False
            self._wait_readable(min(remaining, 0.01))

    def read_batch(self, max_samples: int = 1000, wait_s: float = 0.0) -> list[DisplacementReading]:
        """Up to ``max_samples`` readings, oldest first (tare subtracted).

        Waits at most ``wait_s`` for the first sample when none is queued.
        Raises :class:`SensorDisconnected` on a serial error or when no frame
        arrived for :attr:`no_data_timeout_s`.
        """
        if int(max_samples) < 1:
            raise ValueError(f"max_samples must be >= 1, got {max_samples!r}")
        self._pump()
        if not self._queue and wait_s > 0.0:
            self._wait_for_frames(float(wait_s))
        if not self._queue:
            silence = time.monotonic() - self._last_frame_time
            if silence > self.no_data_timeout_s:
                raise SensorDisconnected(
                    f"no data from ILD1320 on {self._port} for {silence:.3f} s "
                    f"(limit {self.no_data_timeout_s:.3f} s = {self._no_data_periods} sample periods)"
                )
            return []
        count = min(int(max_samples), len(self._queue))
        tare = self._tare_m
        readings = []
        for _ in range(count):
            t_s, value, raw = self._queue.popleft()
            readings.append(DisplacementReading(t_s, value if isinstance(value, MeasurementError) else value - tare,
                                                raw - tare))
        return readings

    # ------------------------------------------------------------------ commands
    def _command(self, text: str) -> CommandReply:
        port = self._require_port()
        self._pump()  # frames received so far keep the current clock model
        self._decoder.clear_non_frame_bytes()
        try:
            port.write(command_bytes(text))
        except serial.SerialTimeoutException as exc:
            raise SensorError(f"writing {text!r} to {self._port} timed out") from exc
        except (serial.SerialException, OSError) as exc:
            raise self._io_error(exc) from exc
        deadline = time.monotonic() + self._timeout_s
        while True:
            buffer = self._decoder.non_frame_bytes()
            end = find_reply_end(buffer)
            if end is not None:
                self._decoder.consume_non_frame_bytes(end)
                return parse_reply(buffer[:end], text)
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                silent = time.monotonic() - self._last_frame_time > self.no_data_timeout_s
                error = SensorDisconnected if silent else SensorError
                raise error(f"no reply to {text!r} from ILD1320 on {self._port} within {self._timeout_s} s")
            self._wait_readable(min(remaining, 0.01))
            self._pump()

    def info(self) -> SensorInfo:
        """Query ``GETINFO`` (name, serial number, measuring range, ...)."""
        self._info = self._ask(getinfo_command(), parse_getinfo_reply, time.monotonic() + self._timeout_s)
        return self._info

    def measuring_rate(self) -> float:
        """Query the measuring rate (Hz) from the sensor; a non-ILD1320 rate is a :class:`SensorError`."""
        rate_hz = parse_measrate_reply(self._command(measrate_command()))
        if not math.isclose(rate_hz, self._rate_hz):
            self._rate_hz = rate_hz
            self._clock.reset(rate_hz, self._latency_s(rate_hz))
        return rate_hz

    def _apply_rate(self, rate_hz: float) -> None:
        self._command(measrate_command(rate_hz))
        actual = self.measuring_rate()
        if not math.isclose(actual, rate_hz):
            raise SensorError(f"ILD1320 on {self._port} reports {actual:g} Hz after setting {rate_hz:g} Hz")
        self._clock.reset(rate_hz, self._latency_s(rate_hz))

    def set_measuring_rate(self, rate_hz: float) -> None:
        """Set the rate (250, 500, 1000 or 2000 Hz) and verify it; kept across reconnects."""
        rate = validate_measuring_rate_hz(rate_hz)
        self._require_port()
        self._apply_rate(rate)
        self._requested_rate_hz = rate

    def set_laser(self, on: bool) -> None:
        """Switch the laser on or off (``LASERPOW``, command name unverified)."""
        self._command(laser_command(bool(on)))

    def laser_is_on(self) -> bool:
        return parse_laser_reply(self._command(laser_command(None)))

    # ------------------------------------------------------------------ tare
    def tare(self, averaging_samples: int = 20, timeout_s: float | None = None) -> float:
        """Software zero on the mean of the next ``averaging_samples`` valid values.

        The samples stay queued for :meth:`read_batch`. The offset applies to
        every reading returned afterwards. Returns the offset in metres.
        """
        n = int(averaging_samples)
        if not 1 <= n <= (self._recent_valid_m.maxlen or 0):
            raise ValueError(
                f"averaging_samples must be in [1, {self._recent_valid_m.maxlen}], got {averaging_samples!r}")
        self._pump()
        limit = timeout_s if timeout_s is not None else max(self._timeout_s, 4.0 * n / self._rate_hz)
        deadline = time.monotonic() + float(limit)
        start = self._valid_count
        while self._valid_count - start < n:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                raise SensorError(
                    f"tare failed: {self._valid_count - start} of {n} valid samples from {self._port} in {limit} s"
                )
            self._wait_readable(min(remaining, 0.01))
            self._pump()
        values = list(self._recent_valid_m)[-n:]
        self._tare_m = math.fsum(values) / n
        return self._tare_m

    def set_tare(self, offset_m: float) -> None:
        self._tare_m = validated_tare_offset_m(offset_m)


def describe_ild1320(
    port: str,
    expected: LaserSensorExpectation = LaserSensorExpectation(),
    *,
    baudrate: int = DEFAULT_BAUDRATE,
    timeout_s: float = 0.5,
    serial_factory: Callable[..., Any] | None = None,
) -> LaserSensorReport:
    """What is connected on ``port`` and how it differs from ``expected`` -- changes nothing.

    Opens the port, reads ``GETINFO`` and the settings (rate, output, additional
    outputs, hold mode, mastering), closes it and returns
    :func:`~dea_ros.hardware.laser.ild1320_protocol.settings.check_laser_sensor`'s report
    (``report.ok``, ``report.mismatches``, ``report.to_reset``, ``report.lines()``).
    Raises :class:`SensorDisconnected` when the port cannot be opened or the
    sensor does not answer, :class:`SensorError` for an unreadable ``GETINFO``.
    """
    sensor = ILD1320Sensor(
        port, baudrate, timeout_s, measuring_range_m=None, measuring_rate_hz=None,
        enable_rs422_output=False, serial_factory=serial_factory,
    )
    sensor._open_port()
    sensor._configuring = True
    try:
        output = sensor._resynchronise()
        settings = dataclasses.replace(sensor.read_settings(), output=output)
        if output not in (None, "NONE"):  # the stream as it was
            sensor._command(output_command(output))
    except (serial.SerialException, OSError) as exc:
        raise SensorDisconnected(f"I/O error while reading ILD1320 on {port}: {exc}") from exc
    finally:
        sensor.close()
    return check_laser_sensor(settings, expected)
