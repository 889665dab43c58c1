"""Micro-Epsilon ILD1320 backend over a serial port (pyserial).

:class:`ILD1320Sensor` implements :class:`~dea_ros.hardware.laser.DisplacementSensor`
for the optoNCDT 1320 on an RS422/USB adapter (or on the pty of
:class:`~dea_ros.hardware.ild1320_emulator.ILD1320Emulator`). Protocol details
are in :mod:`~dea_ros.hardware.ild1320_protocol`.

Reading
-------
All bytes waiting in the OS buffer are read at every :meth:`~ILD1320Sensor.read_batch`
(and while waiting for command replies), decoded by a
:class:`~dea_ros.hardware.ild1320_protocol.FrameDecoder` that also separates the
interleaved ASCII replies, time-stamped, and queued; ``read_batch`` returns the
oldest ``max_samples`` of the queue with the tare offset subtracted.

Acquisition time stamps (:class:`SampleClock`)
----------------------------------------------
The sensor sends no time stamps, so the time of each sample is reconstructed
from the measuring rate ``f`` and the arrival time of the chunk of bytes that
contained it:

1. The sensor streams continuously, one value per cycle, so the *newest* value
   of a chunk read right after it arrived left the sensor at most about one
   adapter/OS latency before the arrival time ``t_arr`` (``time.monotonic()``
   just after the read). It was acquired :data:`OUTPUT_DELAY_CYCLES` cycles
   before it was output (manual ch. 6.4: 1.5 ms at 2 kHz) plus the 3-byte
   transmission time, so ``t_arr - latency`` is an *upper bound* of its
   acquisition time. The ``n`` values of a chunk are one cycle apart:
   ``t_i = t_first + i / f``.
2. A sample clock ``t_first(k) = t_next`` is predicted from the previous chunk
   and compared with the bound ``c = t_arr - latency - (n - 1) / f``:

   * ``c < t_next`` -- the prediction is too late (it can never be later than a
     bound): move it down, by at most half a period per chunk so time stamps
     stay strictly increasing (spacing >= 0.5/f at chunk boundaries);
   * ``0 <= c - t_next <= gap_threshold_s`` -- ordinary transport jitter: no
     change, but if *every* chunk within ``drift_window_s`` (0.5 s) arrived
     late, the smallest of these deviations is clock drift: move up by it;
   * ``c - t_next > 0.75 / f`` and the decoder dropped bytes in front of a
     sample of the chunk (corrupted frames): the missing whole periods are
     skipped just before that sample;
   * ``c - t_next > gap_threshold_s`` (50 ms) without dropped bytes: the sensor
     was silent (samples were never sent): skip the missing periods. Shorter
     unexplained delays are taken for transport delay, not for lost samples.

The result is the lower envelope of the arrival times -- the least-delayed
chunks define the clock -- tracking crystal drift, independent of how often
``read_batch`` is called, with an error of about the minimum transport latency
(sub-millisecond on a pty, the USB latency timer on a real adapter).

Disconnects
-----------
A serial exception (port vanished, EIO) closes the port and raises
:class:`~dea_ros.hardware.laser.SensorDisconnected`; so does silence: no valid
frame for ``no_data_timeout_periods`` sample periods (at least
``min_no_data_timeout_s``). After silence the backend recovers by itself when
frames arrive again; after a serial error call :meth:`ILD1320Sensor.reconnect`
(retries with exponential backoff).
"""
from __future__ import annotations

import collections
import math
import select
import time
from typing import Any, Callable, Optional, Sequence, Union

import serial

from dea_ros.hardware.ild1320_protocol import (
    BYTES_PER_VALUE,
    DEFAULT_BAUDRATE,
    DEFAULT_MEASURING_RANGE_M,
    OUTPUT_DELAY_CYCLES,
    SERIAL_BYTESIZE,
    SERIAL_PARITY,
    SERIAL_STOPBITS,
    CommandReply,
    FrameDecoder,
    SensorInfo,
    command_bytes,
    find_reply_end,
    getinfo_command,
    laser_command,
    measrate_command,
    output_command,
    parse_getinfo_reply,
    parse_laser_reply,
    parse_measrate_reply,
    parse_reply,
    validate_measuring_rate_hz,
)
from dea_ros.hardware.laser import (
    DisplacementReading,
    DisplacementSensor,
    MeasurementError,
    SensorDisconnected,
    SensorError,
    validated_tare_offset_m,
)

__all__ = ["SampleClock", "ILD1320Sensor"]

_READ_CHUNK_BYTES = 65536
_BITS_PER_BYTE_8N1 = 10


class SampleClock:
    """Reconstructs acquisition times of a fixed-rate stream from chunk arrival times.

    See the module docstring for the method. ``latency_s`` is the nominal delay
    from acquisition to arrival of a sample (output delay plus transmission).
    Between corrections the stamps are exactly ``1 / rate_hz`` apart.
    """

    def __init__(
        self,
        rate_hz: float,
        latency_s: float = 0.0,
        *,
        gap_threshold_s: float = 0.05,
        drift_window_s: float = 0.5,
    ) -> None:
        self._rate_hz = self._positive("rate_hz", rate_hz)
        self._latency_s = self._non_negative("latency_s", latency_s)
        self._gap_threshold_s = self._positive("gap_threshold_s", gap_threshold_s)
        self._drift_window_s = self._positive("drift_window_s", drift_window_s)
        self._t_next: Optional[float] = None
        self._last_stamp = -math.inf  # stamps stay increasing across resets
        self._window_start = 0.0
        self._window_min_residual = math.inf
        self.periods_skipped = 0

    @staticmethod
    def _positive(name: str, value: float) -> float:
        result = float(value)
        if not (math.isfinite(result) and result > 0.0):
            raise ValueError(f"{name} must be positive, got {value!r}")
        return result

    @staticmethod
    def _non_negative(name: str, value: float) -> float:
        result = float(value)
        if not (math.isfinite(result) and result >= 0.0):
            raise ValueError(f"{name} must be >= 0, got {value!r}")
        return result

    @property
    def rate_hz(self) -> float:
        return self._rate_hz

    @property
    def latency_s(self) -> float:
        return self._latency_s

    def reset(self, rate_hz: Optional[float] = None, latency_s: Optional[float] = None) -> None:
        """Forget the anchor (next chunk re-anchors); optionally change rate/latency.

        Stamps stay strictly increasing across a reset: the new anchor is at
        least half a period after the last stamp given out.
        """
        if rate_hz is not None:
            self._rate_hz = self._positive("rate_hz", rate_hz)
        if latency_s is not None:
            self._latency_s = self._non_negative("latency_s", latency_s)
        self._t_next = None

    def stamp(
        self,
        n_samples: int,
        arrival_time_s: float,
        *,
        loss_before: Optional[Sequence[bool]] = None,
        loss_after: bool = False,
    ) -> list[float]:
        """Acquisition times (s) of ``n_samples`` samples that arrived at ``arrival_time_s``.

        ``loss_before[i]`` is True when frames may have been lost just before
        sample ``i`` (the decoder dropped bytes there, possibly in an earlier
        chunk); ``loss_after`` when bytes were dropped after the last sample.
        A detected gap is inserted before the last flagged sample (or before
        the first one when unflagged); with ``loss_after`` a positive deviation
        is ambiguous and does not count for the drift correction.
        """
        n = int(n_samples)
        if n <= 0:
            return []
        flags = [False] * n if loss_before is None else [bool(f) for f in loss_before]
        if len(flags) != n:
            raise ValueError(f"loss_before has {len(flags)} flags for {n} samples")
        arrival = float(arrival_time_s)
        period = 1.0 / self._rate_hz
        bound_first = arrival - self._latency_s - (n - 1) * period
        if self._t_next is None:
            t_first = max(bound_first, self._last_stamp + 0.5 * period)
            times = [t_first + i * period for i in range(n)]
            self._t_next = times[-1] + period
            self._last_stamp = times[-1]
            self._window_start = arrival
            self._window_min_residual = math.inf
            return times
        last_loss = max((i for i, flag in enumerate(flags) if flag), default=None)
        error = bound_first - self._t_next
        shift = 0.0
        skip, skip_at = 0, n
        if error < 0.0:
            shift = max(error, -0.5 * period)  # prediction too late: move down, bounded
        elif last_loss is not None and error > 0.75 * period:
            skip, skip_at = int(round(error / period)), last_loss  # lost frames
        elif error > max(self._gap_threshold_s, 0.75 * period):
            skip, skip_at = int(round(error / period)), 0  # silence / undetected loss
        if not (loss_after and error > 0.0):
            residual = error - shift - skip * period
            self._window_min_residual = min(self._window_min_residual, residual)
        if arrival - self._window_start >= self._drift_window_s:
            # every chunk of the window arrived later than predicted: the sensor
            # clock is slower than nominal (or the anchor was late) -> move up
            if math.isfinite(self._window_min_residual) and self._window_min_residual > 0.0:
                shift += self._window_min_residual
            self._window_start = arrival
            self._window_min_residual = math.inf
        self.periods_skipped += skip
        t_first = self._t_next + shift
        times = [t_first + (i + (skip if i >= skip_at else 0)) * period for i in range(n)]
        self._t_next = times[-1] + period
        self._last_stamp = times[-1]
        return times


class ILD1320Sensor(DisplacementSensor):
    """ILD1320 on a serial port; see the module docstring.

    Parameters
    ----------
    port:
        Serial device (``/dev/ttyUSB0``, the emulator's pty or its symlink).
    baudrate:
        921600 (factory setting). 8N1 framing is fixed.
    timeout_s:
        Reply timeout of each ASCII command and write timeout, seconds.
    measuring_range_m:
        Measuring range for the conversion; ``None`` takes it from ``GETINFO``
        (falls back to 10 mm if the reply has none).
    measuring_rate_hz:
        Rate to set on every :meth:`open` (``None``: keep the sensor's setting).
    enable_rs422_output:
        Send ``OUTPUT RS422`` on :meth:`open` so that values are streamed.
    no_data_timeout_periods, min_no_data_timeout_s:
        Silence longer than ``max(periods / rate, min)`` means disconnected.
    serial_factory:
        Replaces ``serial.Serial`` (keyword arguments as pyserial's).
    """

    def __init__(
        self,
        port: str,
        baudrate: int = DEFAULT_BAUDRATE,
        timeout_s: float = 0.5,
        *,
        measuring_range_m: Optional[float] = None,
        measuring_rate_hz: Optional[float] = None,
        enable_rs422_output: bool = True,
        no_data_timeout_periods: int = 200,
        min_no_data_timeout_s: float = 0.3,
        max_queued_samples: int = 100_000,
        serial_factory: Optional[Callable[..., Any]] = None,
    ) -> None:
        self._port = str(port)
        self._baudrate = int(baudrate)
        if self._baudrate <= 0:
            raise ValueError(f"baudrate must be positive, got {baudrate!r}")
        self._timeout_s = float(timeout_s)
        if not (math.isfinite(self._timeout_s) and self._timeout_s > 0.0):
            raise ValueError(f"timeout_s must be positive, got {timeout_s!r}")
        if measuring_range_m is not None and not (float(measuring_range_m) > 0.0):
            raise ValueError(f"measuring_range_m must be positive, got {measuring_range_m!r}")
        self._range_override_m = None if measuring_range_m is None else float(measuring_range_m)
        self._requested_rate_hz = (
            None if measuring_rate_hz is None else validate_measuring_rate_hz(measuring_rate_hz)
        )
        self._enable_output = bool(enable_rs422_output)
        if int(no_data_timeout_periods) < 1:
            raise ValueError(f"no_data_timeout_periods must be >= 1, got {no_data_timeout_periods!r}")
        self._no_data_periods = int(no_data_timeout_periods)
        self._min_no_data_s = float(min_no_data_timeout_s)
        if not (math.isfinite(self._min_no_data_s) and self._min_no_data_s > 0.0):
            raise ValueError(f"min_no_data_timeout_s must be positive, got {min_no_data_timeout_s!r}")
        self._serial_factory = serial_factory or serial.Serial

        self._serial: Optional[Any] = None
        self._lost = False  # port closed because of an I/O error
        self._rate_hz = self._requested_rate_hz or 2000.0
        self._info: Optional[SensorInfo] = None
        self._decoder = FrameDecoder(
            self._range_override_m or DEFAULT_MEASURING_RANGE_M, keep_non_frame_bytes=True
        )
        self._clock = SampleClock(self._rate_hz, self._latency_s(self._rate_hz))
        self._queue: collections.deque[tuple[float, Union[float, MeasurementError]]] = collections.deque()
        self._max_queued = int(max_queued_samples)
        if self._max_queued < 1:
            raise ValueError(f"max_queued_samples must be >= 1, got {max_queued_samples!r}")
        self._recent_valid_m: collections.deque[float] = collections.deque(maxlen=10_000)
        self._valid_count = 0
        self._tare_m = 0.0
        self._last_frame_time = -math.inf
        self.samples_dropped_queue_full = 0

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
    def open(self) -> None:
        """Open the port, read ``GETINFO``, enable RS422 output, set/read the rate.

        Raises :class:`SensorDisconnected` if the port cannot be opened or the
        sensor does not answer, :class:`SensorError` for refused commands.
        """
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
        try:
            port.reset_input_buffer()
            info = self.info()
            range_m = self._range_override_m or info.measuring_range_m or DEFAULT_MEASURING_RANGE_M
            self._decoder.measuring_range_m = range_m
            if self._enable_output:
                self._command(output_command("RS422"))
            if self._requested_rate_hz is not None:
                self._apply_rate(self._requested_rate_hz)
            else:
                self.measuring_rate()
        except (serial.SerialException, OSError) as exc:
            self._close_port()
            raise SensorDisconnected(f"I/O error while configuring ILD1320 on {self._port}: {exc}") from exc
        except BaseException:
            self._close_port()
            raise

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
        :class:`SensorDisconnected` if not connected within ``timeout_s``.
        """
        deadline = time.monotonic() + float(timeout_s)
        backoff = float(initial_backoff_s)
        if not (backoff > 0.0 and float(max_backoff_s) >= backoff):
            raise ValueError("need 0 < initial_backoff_s <= max_backoff_s")
        attempts = 0
        last_error: Optional[BaseException] = None
        while True:
            attempts += 1
            self._close_port()
            try:
                self.open()
                if self._wait_for_frames(min(max(deadline - time.monotonic(), 0.0), self.no_data_timeout_s)):
                    return
                raise SensorDisconnected(f"ILD1320 on {self._port} opened but sends no data")
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
        times = self._clock.stamp(
            len(samples),
            arrival_time_s,
            loss_before=[sample.discarded_before > 0 for sample in samples],
            loss_after=self._decoder.discarded_since_last_frame > 0,
        )
        for t_s, sample in zip(times, samples):
            if len(self._queue) >= self._max_queued:
                self._queue.popleft()
                self.samples_dropped_queue_full += 1
            self._queue.append((t_s, sample.value))
            if sample.is_valid:
                self._recent_valid_m.append(sample.value)
                self._valid_count += 1
        self._last_frame_time = arrival_time_s
        return len(samples)

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
            t_s, value = self._queue.popleft()
            if not isinstance(value, MeasurementError):
                value = value - tare
            readings.append(DisplacementReading(t_s, value))
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
        self._info = parse_getinfo_reply(self._command(getinfo_command()))
        return self._info

    def measuring_rate(self) -> float:
        """Query the measuring rate (Hz) from the sensor."""
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
    def tare(self, averaging_samples: int = 20, timeout_s: Optional[float] = None) -> float:
        """Software zero on the mean of the next ``averaging_samples`` valid values.

        The samples stay queued for :meth:`read_batch`. The offset applies to
        every reading returned afterwards. Returns the offset in metres.
        """
        n = int(averaging_samples)
        if not 1 <= n <= (self._recent_valid_m.maxlen or 0):
            raise ValueError(f"averaging_samples must be in [1, {self._recent_valid_m.maxlen}], got {averaging_samples!r}")
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
