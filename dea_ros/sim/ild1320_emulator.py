"""The ILD1320 laser sensor emulated on a pseudo-terminal (what ``dea-ros rig up`` and the mock rig read).

:class:`ILD1320Emulator` plays an :class:`~dea_ros.sim.ild1320_device.ILD1320Device` on the
master side of a pty (``os.openpty``, raw mode) in a background thread, so that the real
backend :class:`~dea_ros.hardware.laser.ild1320_serial.ILD1320Sensor` (pyserial) can open
:attr:`ILD1320Emulator.port_path` -- or the optional :attr:`~ILD1320Emulator.symlink`, e.g.
:data:`DEFAULT_SYMLINK_PATH` -- exactly like the device over its USB-RS422 adapter. The
thread answers commands as they arrive and writes the due frames in batches every
``batch_interval_s`` (default 2 ms, as a USB adapter does), in real time
(``time.monotonic()``).
"""
from __future__ import annotations

import errno
import os
import select
import threading
import time
import tty
from typing import Any

from .ild1320_device import DisplacementSource, ILD1320Device, positive_finite

__all__ = ["ILD1320Emulator", "DEFAULT_SYMLINK_PATH"]

#: Conventional symlink path for the mock hardware node (pass it as ``symlink``).
DEFAULT_SYMLINK_PATH = "/tmp/dea_ros_mock_laser"


class ILD1320Emulator(ILD1320Device):
    """An ILD1320 on a pty, streaming in a background thread (see the module docstring).

    * ``displacement_source`` and ``settings``: the device's (:class:`ILD1320Device`:
      measuring rate and range, serial number, model name, a previous user's settings);
    * ``symlink``: optional path of a symbolic link to the pty slave, e.g.
      :data:`DEFAULT_SYMLINK_PATH`, created by :meth:`start` (an existing symlink there is
      replaced, any other file is refused) and removed by :meth:`stop`;
    * ``batch_interval_s``: period of the streaming writes (1-5 ms is realistic for a USB
      adapter);
    * ``output_buffer_limit_bytes``: bytes held while the reader does not read; the oldest
      are dropped beyond it (counted in ``bytes_dropped_overflow``).
    """

    def __init__(
        self,
        displacement_source: DisplacementSource | None = None,
        *,
        symlink: str | None = None,
        batch_interval_s: float = 0.002,
        output_buffer_limit_bytes: int = 65536,
        **settings: Any,
    ) -> None:
        super().__init__(displacement_source, **settings)
        self._batch_interval_s = positive_finite("batch_interval_s", batch_interval_s)
        self._out_limit = int(output_buffer_limit_bytes)
        if self._out_limit < 1024:
            raise ValueError(f"output_buffer_limit_bytes must be >= 1024, got {output_buffer_limit_bytes!r}")
        self._symlink = None if symlink is None else os.fspath(symlink)
        self._thread: threading.Thread | None = None
        self._stop_event = threading.Event()
        self._master_fd: int | None = None
        self._slave_fd: int | None = None
        self._wake_r: int | None = None
        self._wake_w: int | None = None
        self._port_path: str | None = None
        self._out = bytearray()
        self.bytes_dropped_overflow = 0
        self.thread_error: BaseException | None = None

    # ------------------------------------------------------------------ lifecycle
    @property
    def port_path(self) -> str:
        """Path of the pty slave device to open as the serial port."""
        if self._port_path is None:
            raise RuntimeError("emulator not started")
        return self._port_path

    @property
    def symlink(self) -> str | None:
        """Path of the symlink to :attr:`port_path` (``None`` if not requested)."""
        return self._symlink

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> ILD1320Emulator:
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
        self._restart_stream(time.monotonic())
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

    def __enter__(self) -> ILD1320Emulator:
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
        """Wake the thread up now (it otherwise sleeps until the next batch)."""
        if self._wake_w is not None:
            try:
                os.write(self._wake_w, b"x")
            except OSError:
                pass

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

    def _send(self, data: bytes) -> None:
        """Queue ``data`` for the pty (the oldest bytes are dropped beyond the buffer limit)."""
        if not data:
            return
        self._out += data
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
        self._receive(data, now)
