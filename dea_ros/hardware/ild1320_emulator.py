"""ILD1320 emulator on a pseudo-terminal, and a serial-free mock sensor.

:class:`ILD1320Emulator` plays the sensor on the master side of a pty
(``os.openpty``, raw mode) in a background thread, so that the real backend
:class:`~dea_ros.hardware.ild1320_sensor.ILD1320Sensor` (pyserial) can open
:attr:`ILD1320Emulator.port_path` -- or the optional :attr:`symlink`, e.g.
``/tmp/dea_ros_mock_laser`` -- exactly like the device:

* it answers the ASCII commands ``GETINFO``, ``MEASRATE [kHz]``,
  ``LASERPOW [FULL|OFF]``, ``OUTPUT [NONE|RS422|ANALOG]``, ``OUTADD_RS422
  [NONE|<values>]``, ``OUTHOLD [NONE|0|<n>]`` and ``MASTERMV [NONE|MASTER <mm>]``
  with the reply format
  of :mod:`~dea_ros.hardware.ild1320_protocol` (body lines, CR LF, ``->``), and an
  ``Exxx`` error for unknown commands or invalid parameters (the error numbers
  :data:`ERROR_UNKNOWN_COMMAND` etc. are this emulator's choice, not taken from
  the manual);
* it streams binary frames at the configured measuring rate in real time: the
  sample ``k`` is acquired at ``t_k = t_0 + k / rate`` (``time.monotonic()``
  seconds), its value is ``displacement_source(t_k)`` (metres from the start of
  the measuring range), quantised to the sensor's digital resolution (values
  beyond the range reserves become the "too close"/"too far" error codes, NaN
  becomes "no peak", a :class:`~dea_ros.hardware.laser.MeasurementError`
  returned by the source is sent as its code), and it is output
  :data:`~dea_ros.hardware.ild1320_protocol.OUTPUT_DELAY_CYCLES` cycles after
  acquisition, like the sensor. Frames are written in batches every
  ``batch_interval_s`` (default 2 ms) to keep the CPU load low; replies are
  written between frames, as the sensor keeps streaming while it answers;
* settings a previous user may have left (constructor arguments, or set with the
  commands): ``mastering`` (the 18-bit shifted output of a mastered sensor, see
  :func:`~dea_ros.hardware.ild1320_protocol.mastered_displacement_to_code`),
  ``additional_outputs`` (values sent after each distance, H flags ``11``) and
  ``output_hold`` (an error value replaced by the last valid one);
* fault injection for tests: :meth:`~ILD1320Emulator.inject_garbage` (``raw=True``:
  truly random bytes that may form frames), :meth:`~ILD1320Emulator.corrupt_next`,
  :meth:`~ILD1320Emulator.pause` (silence: no frames, no replies -- a pulled
  cable) and :meth:`~ILD1320Emulator.misbehave`: wrong replies (a ``MEASRATE``
  query answering 0 or 7 kHz, ``GETINFO`` with another measuring range or model,
  any raw reply), commands acknowledged but ignored, and random bytes inserted
  into or dropped from the stream.

:class:`MockDisplacementSensor` implements
:class:`~dea_ros.hardware.laser.DisplacementSensor` without any serial port: it
evaluates the same kind of callback at the exact sample times, with the same
quantisation and error codes.
"""
from __future__ import annotations

import collections
import errno
import math
import os
import random
import select
import threading
import time
import tty
from typing import Callable, Iterable, NamedTuple, Optional, Sequence, Union

from dea_ros.hardware.ild1320_protocol import (
    ALLOWED_MEASURING_RATES_HZ,
    DEFAULT_MEASURING_RANGE_M,
    ERROR_CODES,
    FLAG_L,
    FLAG_M,
    MAX_RAW_CODE,
    OUTPUT_DELAY_CYCLES,
    code_to_displacement_m,
    displacement_to_code,
    encode_value,
    mastered_displacement_to_code,
    parse_command_line,
    render_error,
    render_reply,
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

__all__ = [
    "DEFAULT_SYMLINK_PATH",
    "DisplacementSource",
    "EmittedSample",
    "ILD1320Emulator",
    "MockDisplacementSensor",
    "ERROR_UNKNOWN_COMMAND",
    "ERROR_WRONG_PARAMETER_COUNT",
    "ERROR_INVALID_PARAMETER",
    "ERROR_LINE_TOO_LONG",
]

#: ``displacement_source(t_s)``: displacement in metres from the start of the
#: measuring range at acquisition time ``t_s`` (``time.monotonic()`` seconds), or
#: a :class:`MeasurementError`, or NaN for "no target".
DisplacementSource = Callable[[float], Union[float, MeasurementError]]

#: Conventional symlink path for the mock hardware node (pass it as ``symlink``).
DEFAULT_SYMLINK_PATH = "/tmp/dea_ros_mock_laser"

#: Emulator error replies (numbers chosen here; the manual's list was not found).
ERROR_UNKNOWN_COMMAND = (210, "Unknown command")
ERROR_WRONG_PARAMETER_COUNT = (220, "Wrong parameter count")
ERROR_INVALID_PARAMETER = (232, "Invalid parameter value")
ERROR_LINE_TOO_LONG = (214, "Entered command too long")
ERROR_TIMEOUT = (104, "Timeout")

#: Additional values the emulator can send (OUTADD_RS422), in output order.
ADDITIONAL_OUTPUTS = ("SHUTTER", "COUNTER", "TIMESTAMP", "INTENSITY", "STATE", "DIST_RAW")

_UNSET = object()

_MAX_COMMAND_LINE_BYTES = 256


class EmittedSample(NamedTuple):
    """A sample written by the emulator (kept when ``record_limit > 0``)."""

    index: int  #: running number over all emitted samples, from 0
    acquisition_time_s: float  #: ``time.monotonic()`` time of acquisition
    code: int  #: 18-bit value sent (distance or error code)
    value: Union[float, MeasurementError]  #: what ``code`` means (metres from the SMR, or error)
    corrupted: bool  #: True when the frame was deliberately corrupted


def _check_positive(name: str, value: float) -> float:
    result = float(value)
    if not (math.isfinite(result) and result > 0.0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return result


def _constant_mid_range(measuring_range_m: float) -> DisplacementSource:
    mid = 0.5 * measuring_range_m
    return lambda t_s: mid


class ILD1320Emulator:
    """Emulated ILD1320 on a pty; see the module docstring.

    Parameters
    ----------
    displacement_source:
        ``f(t_s) -> metres`` from the start of the measuring range (default: a
        constant mid-range target). Called from the emulator thread.
    measuring_rate_hz:
        Initial measuring rate, one of 250, 500, 1000, 2000 Hz.
    measuring_range_m:
        Measuring range used for the quantisation (10 mm for the ILD1320-10).
    symlink:
        Optional path of a symbolic link to the pty slave, e.g.
        :data:`DEFAULT_SYMLINK_PATH`, created by :meth:`start` (an existing
        symlink there is replaced, any other file is refused) and removed by
        :meth:`stop`.
    batch_interval_s:
        Period of the streaming writes (1-5 ms is realistic for a USB adapter).
    record_limit:
        Keep the last ``record_limit`` emitted samples for tests (0: none).
    seed:
        Seed of the random generator used for garbage and corruption.
    mastering:
        ``(master_position_m, master_value_m)``: the sensor is mastered as a
        previous user left it (``None``: not mastered).
    additional_outputs:
        Additional values sent after each distance (``OUTADD_RS422``), e.g.
        ``("COUNTER",)``.
    output_hold:
        ``OUTHOLD`` mode: ``"NONE"`` (errors sent as errors), ``"0"`` (the last
        valid value is repeated instead of an error) or a number of cycles.
    model_name:
        ``GETINFO`` name (default ``ILD1320-<range in mm>``).
    """

    def __init__(
        self,
        displacement_source: Optional[DisplacementSource] = None,
        *,
        measuring_rate_hz: float = 2000.0,
        measuring_range_m: float = DEFAULT_MEASURING_RANGE_M,
        symlink: Optional[str] = None,
        batch_interval_s: float = 0.002,
        record_limit: int = 0,
        seed: int = 0,
        serial_number: str = "00000000",
        max_catch_up_s: float = 0.5,
        output_buffer_limit_bytes: int = 65536,
        mastering: Optional[tuple[float, float]] = None,
        additional_outputs: Sequence[str] = (),
        output_hold: str = "NONE",
        model_name: Optional[str] = None,
    ) -> None:
        self._range_m = _check_positive("measuring_range_m", measuring_range_m)
        self._source = displacement_source or _constant_mid_range(self._range_m)
        if not callable(self._source):
            raise TypeError(f"displacement_source must be callable, got {displacement_source!r}")
        self._rate_hz = validate_measuring_rate_hz(measuring_rate_hz)
        self._batch_interval_s = _check_positive("batch_interval_s", batch_interval_s)
        self._max_catch_up_s = _check_positive("max_catch_up_s", max_catch_up_s)
        self._out_limit = int(output_buffer_limit_bytes)
        if self._out_limit < 1024:
            raise ValueError(f"output_buffer_limit_bytes must be >= 1024, got {output_buffer_limit_bytes!r}")
        if int(record_limit) < 0:
            raise ValueError(f"record_limit must be >= 0, got {record_limit!r}")
        self._records: collections.deque[EmittedSample] = collections.deque(maxlen=int(record_limit) or 1)
        self._record = int(record_limit) > 0
        self._symlink = None if symlink is None else os.fspath(symlink)
        self._serial_number = str(serial_number)
        self._rng = random.Random(seed)

        self._lock = threading.Lock()
        self._thread: Optional[threading.Thread] = None
        self._stop_event = threading.Event()
        self._master_fd: Optional[int] = None
        self._slave_fd: Optional[int] = None
        self._wake_r: Optional[int] = None
        self._wake_w: Optional[int] = None
        self._port_path: Optional[str] = None

        # streaming state (guarded by _lock where shared with the API)
        self._laser_on = True
        self._output = "RS422"
        self._model_name = model_name or f"ILD1320-{self._range_m * 1e3:g}"
        self._mastering = self._check_mastering(mastering)
        self._additional = self._check_additional(additional_outputs)
        self._hold = self._check_hold(output_hold)
        self._last_valid_code: Optional[int] = None
        self._held_cycles = 0
        # misbehaviour (see misbehave())
        self._reported_rate_khz: Optional[str] = None
        self._reported_range_mm: Optional[float] = None
        self._reported_model: Optional[str] = None
        self._ignored_commands: frozenset[str] = frozenset()
        self._reply_overrides: dict[str, bytes] = {}
        self._drop_byte_probability = 0.0
        self._random_byte_probability = 0.0
        self._segment_t0 = 0.0
        self._segment_next = 0
        self._pause_windows: list[tuple[float, float]] = []
        self._garbage_requests: list[int] = []
        self._corrupt_remaining = 0
        self._next_index = 0
        self._out = bytearray()
        self._tail = bytearray()  # last two bytes queued, for garbage generation
        self._line = bytearray()

        # statistics
        self.frames_emitted = 0
        self.samples_lost_paused = 0
        self.samples_not_output = 0
        self.samples_skipped_lag = 0
        self.frames_corrupted = 0
        self.garbage_bytes_injected = 0
        self.bytes_dropped_overflow = 0
        self.bytes_dropped_fault = 0
        self.random_bytes_inserted = 0
        self.additional_values_emitted = 0
        self.commands_received = 0
        self.source_errors = 0
        self.last_source_error: Optional[BaseException] = None
        self.thread_error: Optional[BaseException] = None

    # ------------------------------------------------------------------ lifecycle
    @property
    def port_path(self) -> str:
        """Path of the pty slave device to open as the serial port."""
        if self._port_path is None:
            raise RuntimeError("emulator not started")
        return self._port_path

    @property
    def symlink(self) -> Optional[str]:
        """Path of the symlink to :attr:`port_path` (``None`` if not requested)."""
        return self._symlink

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> "ILD1320Emulator":
        """Create the pty (and symlink) and start the emulator thread."""
        if self._thread is not None:
            raise RuntimeError("emulator already started")
        master_fd, slave_fd = os.openpty()
        try:
            tty.setraw(slave_fd)
            os.set_blocking(master_fd, False)
            wake_r, wake_w = os.pipe()
        except BaseException:
            os.close(master_fd)
            os.close(slave_fd)
            raise
        os.set_blocking(wake_r, False)
        self._master_fd, self._slave_fd = master_fd, slave_fd
        self._wake_r, self._wake_w = wake_r, wake_w
        self._port_path = os.ttyname(slave_fd)
        try:
            if self._symlink is not None:
                self._create_symlink()
        except BaseException:
            self._close_fds()
            raise
        now = time.monotonic()
        self._segment_t0 = now
        self._segment_next = 0
        self._stop_event.clear()
        self._thread = threading.Thread(target=self._run, name="ild1320-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop and join the thread, close the pty (readers get EIO) and remove the symlink."""
        thread = self._thread
        if thread is not None:
            self._stop_event.set()
            self._wake()
            thread.join(timeout_s)
            if thread.is_alive():
                raise RuntimeError(f"emulator thread did not stop within {timeout_s} s")
            self._thread = None
        self._remove_symlink()
        self._close_fds()

    def __enter__(self) -> "ILD1320Emulator":
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> None:
        self.stop()

    def _create_symlink(self) -> None:
        path = self._symlink
        assert path is not None
        if os.path.islink(path):
            os.unlink(path)
        elif os.path.exists(path):
            raise FileExistsError(f"cannot create emulator symlink: {path!r} exists and is not a symlink")
        os.symlink(self.port_path, path)

    def _remove_symlink(self) -> None:
        path = self._symlink
        if path is None or self._port_path is None:
            return
        try:
            if os.path.islink(path) and os.readlink(path) == self._port_path:
                os.unlink(path)
        except OSError:
            pass

    def _close_fds(self) -> None:
        for name in ("_master_fd", "_slave_fd", "_wake_r", "_wake_w"):
            fd = getattr(self, name)
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
                setattr(self, name, None)

    def _wake(self) -> None:
        if self._wake_w is not None:
            try:
                os.write(self._wake_w, b"x")
            except OSError:
                pass

    # ------------------------------------------------------------------ state / faults
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
    def mastering(self) -> Optional[tuple[float, float]]:
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

    def _check_mastering(self, mastering: Optional[tuple[float, float]]) -> Optional[tuple[float, float]]:
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

    def misbehave(
        self,
        *,
        reported_rate_khz=_UNSET,
        reported_range_mm=_UNSET,
        reported_model=_UNSET,
        ignored_commands=_UNSET,
        reply_overrides=_UNSET,
        drop_byte_probability=_UNSET,
        random_byte_probability=_UNSET,
    ) -> None:
        """Make the emulator misbehave (arguments left out keep their setting; ``None`` restores).

        * ``reported_rate_khz``: text the ``MEASRATE`` query answers (``"0"``, ``"7"``, ...);
        * ``reported_range_mm``: measuring range in the ``GETINFO`` reply (the
          stream keeps the true range);
        * ``reported_model``: name in the ``GETINFO`` reply;
        * ``ignored_commands``: command names acknowledged but not applied;
        * ``reply_overrides``: ``{command name: raw reply bytes}`` sent instead of
          the real reply (include the ``->`` prompt for a complete reply);
        * ``drop_byte_probability`` / ``random_byte_probability``: each byte of
          the measurement stream is dropped / preceded by a random byte with this
          probability.
        """
        with self._lock:
            if reported_rate_khz is not _UNSET:
                self._reported_rate_khz = None if reported_rate_khz is None else str(reported_rate_khz)
            if reported_range_mm is not _UNSET:
                self._reported_range_mm = None if reported_range_mm is None else float(reported_range_mm)
            if reported_model is not _UNSET:
                self._reported_model = None if reported_model is None else str(reported_model)
            if ignored_commands is not _UNSET:
                self._ignored_commands = frozenset(str(c).upper() for c in (ignored_commands or ()))
            if reply_overrides is not _UNSET:
                self._reply_overrides = {
                    str(k).upper(): v.encode("latin-1") if isinstance(v, str) else bytes(v)
                    for k, v in (reply_overrides or {}).items()
                }
            for name, value in (("drop", drop_byte_probability), ("random", random_byte_probability)):
                if value is _UNSET:
                    continue
                p = 0.0 if value is None else float(value)
                if not 0.0 <= p < 1.0:
                    raise ValueError(f"{name}_byte_probability must be in [0, 1), got {value!r}")
                if name == "drop":
                    self._drop_byte_probability = p
                else:
                    self._random_byte_probability = p

    def inject_garbage(self, n_bytes: int, *, raw: bool = False) -> None:
        """Write ``n_bytes`` random bytes between two frames at the next batch.

        By default the bytes never form a valid frame by accident (no L, M, H run,
        also not across the boundary with the bytes written before), so a decoder
        must drop all of them and lose no real frame. With ``raw=True`` they are
        uniformly random: about one position in 64 starts a frame with valid
        flag bits that decodes to some value (what a noisy line does).
        """
        n = int(n_bytes)
        if n < 0:
            raise ValueError(f"n_bytes must be >= 0, got {n_bytes!r}")
        with self._lock:
            self._garbage_requests.append(-n if raw else n)
        self._wake()

    def corrupt_next(self, n_frames: int) -> None:
        """Corrupt the next ``n_frames`` frames (a flag bit flipped or a byte lost)."""
        n = int(n_frames)
        if n < 0:
            raise ValueError(f"n_frames must be >= 0, got {n_frames!r}")
        with self._lock:
            self._corrupt_remaining += n

    def pause(self, seconds: float) -> None:
        """Go silent for ``seconds`` from now: samples due then are lost, commands ignored."""
        duration = float(seconds)
        if not (math.isfinite(duration) and duration >= 0.0):
            raise ValueError(f"pause duration must be >= 0 s, got {seconds!r}")
        now = time.monotonic()
        with self._lock:
            self._pause_windows.append((now, now + duration))

    def is_paused(self, t_s: Optional[float] = None) -> bool:
        """True if the emulator is silent at ``t_s`` (default: now)."""
        t = time.monotonic() if t_s is None else t_s
        with self._lock:
            return any(start <= t < end for start, end in self._pause_windows)

    def emitted_samples(self) -> list[EmittedSample]:
        """Copy of the recorded samples (needs ``record_limit > 0``)."""
        if not self._record:
            raise RuntimeError("construct the emulator with record_limit > 0 to record samples")
        with self._lock:
            return list(self._records)

    # ------------------------------------------------------------------ thread
    def _run(self) -> None:
        master_fd, wake_r = self._master_fd, self._wake_r
        next_batch = time.monotonic()
        try:
            while not self._stop_event.is_set():
                timeout = max(0.0, next_batch - time.monotonic())
                readable, _, _ = select.select([master_fd, wake_r], [], [], timeout)
                if wake_r in readable:
                    try:
                        os.read(wake_r, 4096)
                    except BlockingIOError:
                        pass
                now = time.monotonic()
                if master_fd in readable:
                    self._read_commands(master_fd, now)
                if now >= next_batch:
                    self._emit_due(now)
                    next_batch = now + self._batch_interval_s
                self._flush(master_fd)
        except Exception as exc:  # recorded for tests; the thread must not die silently
            if not self._stop_event.is_set():
                self.thread_error = exc

    def _silent(self, t: float) -> bool:
        # caller holds the lock
        return any(start <= t < end for start, end in self._pause_windows)

    def _queue(self, data: bytes) -> None:
        if not data:
            return
        self._out += data
        self._tail = (self._tail + data)[-2:]
        excess = len(self._out) - self._out_limit
        if excess > 0:
            del self._out[:excess]
            self.bytes_dropped_overflow += excess

    def _flush(self, master_fd: int) -> None:
        while self._out:
            try:
                written = os.write(master_fd, self._out)
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno in (errno.EIO, errno.EAGAIN):
                    return
                raise
            if written <= 0:
                return
            del self._out[:written]

    def _read_commands(self, master_fd: int, now: float) -> None:
        try:
            data = os.read(master_fd, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                return
            raise
        with self._lock:
            if self._silent(now):
                return  # a disconnected sensor hears nothing
        self._line += data
        while True:
            newline = self._line.find(b"\n")
            if newline < 0:
                if len(self._line) > _MAX_COMMAND_LINE_BYTES:
                    self._line.clear()
                    self._emit_due(now)
                    self._queue(render_error(*ERROR_LINE_TOO_LONG))
                return
            raw_line = bytes(self._line[:newline]).strip(b"\r \t")
            del self._line[: newline + 1]
            if not raw_line:
                continue
            self.commands_received += 1
            reply = self._execute(raw_line, now)
            self._emit_due(now)  # frames due before the reply go first
            self._queue(reply)

    def _execute(self, raw_line: bytes, now: float) -> bytes:
        try:
            name, params = parse_command_line(raw_line.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            return render_error(*ERROR_INVALID_PARAMETER)
        with self._lock:
            override = self._reply_overrides.get(name)
            ignored = name in self._ignored_commands and bool(params)
        if override is not None:
            return override
        if ignored:
            return render_reply()  # acknowledged, not applied
        if name == "GETINFO":
            if params:
                return render_error(*ERROR_WRONG_PARAMETER_COUNT)
            return render_reply(self._info_lines())
        if name == "MEASRATE":
            return self._cmd_measrate(params, now)
        if name == "LASERPOW":
            return self._cmd_laserpow(params)
        if name == "OUTPUT":
            return self._cmd_output(params)
        if name == "OUTADD_RS422":
            return self._cmd_outadd(params)
        if name == "OUTHOLD":
            return self._cmd_outhold(params)
        if name == "MASTERMV":
            return self._cmd_mastermv(params, now)
        return render_error(*ERROR_UNKNOWN_COMMAND)

    def _info_lines(self) -> list[str]:
        with self._lock:
            range_mm = self._range_m * 1e3 if self._reported_range_mm is None else self._reported_range_mm
            model = self._reported_model if self._reported_model is not None else self._model_name
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

    def _cmd_outadd(self, params: list[str]) -> bytes:
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

    def _cmd_outhold(self, params: list[str]) -> bytes:
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
                if self._reported_rate_khz is not None:
                    return render_reply([f"MEASRATE {self._reported_rate_khz}"])
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

    def _cmd_laserpow(self, params: list[str]) -> bytes:
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

    def _cmd_output(self, params: list[str]) -> bytes:
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

    def _emit_due(self, now: float) -> None:
        with self._lock:
            garbage = self._garbage_requests
            self._garbage_requests = []
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
            windows = list(self._pause_windows)
            # forget pause windows that are over
            self._pause_windows = [(s, e) for s, e in self._pause_windows if e > now]
        for request in garbage:
            n_bytes = abs(request)
            if not any(s <= now < e for s, e in windows):
                if request < 0:
                    self._queue(bytes(self._rng.randrange(256) for _ in range(n_bytes)))
                else:
                    self._queue(self._make_garbage(n_bytes))
                self.garbage_bytes_injected += n_bytes
        for n in range(first, end):
            t_acq = segment_t0 + n * period
            t_out = t_acq + delay
            if any(s <= t_out < e for s, e in windows):
                self.samples_lost_paused += 1
                continue
            if not streaming:
                self.samples_not_output += 1
                continue
            code = self._sample_code(t_acq, laser_on)
            frame = encode_value(code)
            corrupted = False
            with self._lock:
                if self._corrupt_remaining > 0:
                    self._corrupt_remaining -= 1
                    corrupted = True
            if corrupted:
                frame = self._corrupt(frame)
                self.frames_corrupted += 1
            frame += self._additional_frames(code)
            self._queue(self._stream_faults(frame))
            self.frames_emitted += 1
            if self._record:
                with self._lock:
                    self._records.append(
                        EmittedSample(
                            self._next_index, t_acq, code, code_to_displacement_m(code, self._range_m), corrupted
                        )
                    )
            self._next_index += 1

    def _sample_code(self, t_acq: float, laser_on: bool) -> int:
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
        with self._lock:
            names = self._additional
        if not names:
            return b""
        out = bytearray()
        for name in names:
            if name == "COUNTER":
                values = [self._next_index & MAX_RAW_CODE]
            elif name == "SHUTTER":
                values = [1000]  # 100.0 us exposure
            elif name == "TIMESTAMP":  # two 16-bit words, 10 us units
                ticks = int(time.monotonic() * 1e5) & 0xFFFFFFFF
                values = [ticks & 0xFFFF, ticks >> 16]
            elif name == "INTENSITY":
                values = [32736]  # 50 %
            elif name == "STATE":
                values = [0]
            else:  # DIST_RAW
                values = [code]
            for value in values:
                out += encode_value(value, additional=True)
                self.additional_values_emitted += 1
        return bytes(out)

    def _stream_faults(self, data: bytes) -> bytes:
        with self._lock:
            p_drop, p_random = self._drop_byte_probability, self._random_byte_probability
        if p_drop <= 0.0 and p_random <= 0.0:
            return data
        rng = self._rng
        out = bytearray()
        for byte in data:
            if p_random > 0.0 and rng.random() < p_random:
                out.append(rng.randrange(256))
                self.random_bytes_inserted += 1
            if p_drop > 0.0 and rng.random() < p_drop:
                self.bytes_dropped_fault += 1
                continue
            out.append(byte)
        return bytes(out)

    def _corrupt(self, frame: bytes) -> bytes:
        low, mid, high = frame
        mode = self._rng.randrange(3)
        if mode == 0:  # M byte's flag bit cleared: L, L', H
            return bytes((low, mid & 0x3F, high))
        if mode == 1:  # M byte lost: L, H
            return bytes((low, high))
        return bytes((low, mid, (high & 0x3F) | 0x40))  # H flag turned into M: L, M, M'

    def _make_garbage(self, n_bytes: int) -> bytes:
        buf = bytearray(self._tail[-2:])
        start = len(buf)
        rng = self._rng
        while len(buf) - start < n_bytes:
            byte = rng.randrange(256)
            if (
                byte >> 6 >= 2
                and len(buf) >= 2
                and buf[-2] >> 6 == FLAG_L
                and buf[-1] >> 6 == FLAG_M
            ):
                continue  # would complete an accidental frame
            buf.append(byte)
        return bytes(buf[start:])


class MockDisplacementSensor(DisplacementSensor):
    """Serial-free sensor: evaluates ``displacement_source`` at the sample times.

    Sample ``k`` is acquired at ``t_0 + k / rate`` on ``clock`` (default
    ``time.monotonic``), where ``t_0`` is the time of :meth:`open` (or of the
    last rate change). :meth:`read_batch` returns the samples acquired since the
    previous call (at most ``max_samples``; at most ``max_backlog_s`` of backlog
    is kept), quantised like the ILD1320 (see
    :func:`~dea_ros.hardware.ild1320_protocol.displacement_to_code`) and minus
    the tare offset. :meth:`pause` simulates a lost connection.
    """

    def __init__(
        self,
        displacement_source: Optional[DisplacementSource] = None,
        *,
        measuring_rate_hz: float = 2000.0,
        measuring_range_m: float = DEFAULT_MEASURING_RANGE_M,
        allowed_rates_hz: tuple[float, ...] = ALLOWED_MEASURING_RATES_HZ,
        clock: Callable[[], float] = time.monotonic,
        max_backlog_s: float = 1.0,
    ) -> None:
        self._range_m = _check_positive("measuring_range_m", measuring_range_m)
        self._source = displacement_source or _constant_mid_range(self._range_m)
        if not callable(self._source):
            raise TypeError(f"displacement_source must be callable, got {displacement_source!r}")
        self._allowed = tuple(float(r) for r in allowed_rates_hz)
        self._rate_hz = self._validate_rate(measuring_rate_hz)
        self._clock = clock
        self._max_backlog_s = _check_positive("max_backlog_s", max_backlog_s)
        self._open = False
        self._t0 = 0.0
        self._next = 0
        self._tare_m = 0.0
        self._paused_until = -math.inf
        self.samples_skipped_backlog = 0
        self.samples_lost_paused = 0

    def _validate_rate(self, rate_hz: float) -> float:
        value = float(rate_hz)
        for allowed in self._allowed:
            if math.isclose(value, allowed, rel_tol=1e-9):
                return allowed
        raise ValueError(f"measuring rate {rate_hz!r} Hz not supported (allowed: {list(self._allowed)} Hz)")

    def _due_end(self, now: float) -> int:
        return max(0, math.floor((now - self._t0) * self._rate_hz) + 1)

    def _value(self, t_s: float) -> Union[float, MeasurementError]:
        return code_to_displacement_m(displacement_to_code(self._source(t_s), self._range_m), self._range_m)

    def open(self) -> None:
        self._open = True
        self._t0 = self._clock()
        self._next = 0

    def close(self) -> None:
        self._open = False

    def pause(self, seconds: float) -> None:
        """No data for ``seconds``: ``read_batch`` raises :class:`SensorDisconnected`."""
        duration = float(seconds)
        if not (math.isfinite(duration) and duration >= 0.0):
            raise ValueError(f"pause duration must be >= 0 s, got {seconds!r}")
        self._paused_until = self._clock() + duration

    def _require_open(self) -> None:
        if not self._open:
            raise SensorError("mock displacement sensor is not open")

    def is_connected(self) -> bool:
        return self._open and self._clock() >= self._paused_until

    def read_batch(self, max_samples: int = 1000) -> list[DisplacementReading]:
        if int(max_samples) < 1:
            raise ValueError(f"max_samples must be >= 1, got {max_samples!r}")
        self._require_open()
        now = self._clock()
        end = self._due_end(now)
        if now < self._paused_until:
            self.samples_lost_paused += max(0, end - self._next)
            self._next = max(self._next, end)
            raise SensorDisconnected(f"mock sensor silent for another {self._paused_until - now:.3f} s")
        backlog_limit = int(self._max_backlog_s * self._rate_hz)
        if end - self._next > backlog_limit:
            skipped = end - self._next - backlog_limit
            self.samples_skipped_backlog += skipped
            self._next += skipped
        stop = min(end, self._next + int(max_samples))
        readings = []
        for k in range(self._next, stop):
            t_s = self._t0 + k / self._rate_hz
            value = self._value(t_s)
            if not isinstance(value, MeasurementError):
                value -= self._tare_m
            readings.append(DisplacementReading(t_s, value))
        self._next = stop
        return readings

    def tare(self, averaging_samples: int = 1) -> float:
        """Zero on the mean of the last ``averaging_samples`` sample values (valid ones)."""
        self._require_open()
        n = int(averaging_samples)
        if n < 1:
            raise ValueError(f"averaging_samples must be >= 1, got {averaging_samples!r}")
        end = self._due_end(self._clock())
        values = [self._value(self._t0 + k / self._rate_hz) for k in range(max(0, end - n), end)]
        valid = [v for v in values if not isinstance(v, MeasurementError)]
        if not valid:
            raise SensorError(f"tare failed: none of the last {n} samples is a valid displacement")
        self._tare_m = math.fsum(valid) / len(valid)
        return self._tare_m

    @property
    def tare_offset_m(self) -> float:
        return self._tare_m

    def set_tare(self, offset_m: float) -> None:
        self._tare_m = validated_tare_offset_m(offset_m)

    def set_measuring_rate(self, rate_hz: float) -> None:
        """Change the rate; samples due but not yet read at the old rate are dropped."""
        rate = self._validate_rate(rate_hz)
        if self._open:
            last_t = self._t0 + (self._next - 1) / self._rate_hz
            self._t0 = max(self._clock(), last_t) + 1.0 / rate
            self._next = 0
        self._rate_hz = rate

    def measuring_rate(self) -> float:
        return self._rate_hz

    def reconnect(self) -> None:
        if self._clock() < self._paused_until:
            raise SensorDisconnected("mock sensor still silent; reconnect failed")
        self.close()
        self.open()
