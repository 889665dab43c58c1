""":class:`BagWriter`: write a rosbag2 MCAP bag directory without ROS.

Layout (as ``ros2 bag record -s mcap -o <dir>``): ``<dir>/<dirname>_0.mcap`` and, on close,
``<dir>/metadata.yaml``. See the package docstring (:mod:`dea_ros.bag`) for the exact format
choices and how to open the result in ``ros2 bag``, Foxglove and PlotJuggler.

Crash safety: the open chunk is closed and handed to the OS at least every ``flush_period_s``
(by the writing thread when it writes, else by a background flusher thread), so after SIGKILL of
the recording process the ``.mcap`` holds every message older than ``flush_period_s``. Such an
unfinished file has no summary/footer and there is no ``metadata.yaml``: run
:func:`dea_ros.bag.recover_bag` on the directory (``BagReader`` can also read it directly).
``fsync=True`` additionally survives power loss, at the cost of one ``fsync`` per flush.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from .. import __version__
from ..errors import BagError
from .definitions import MessageDefinitionStore, normalize_type_name
from .files import write_text_atomic
from .mcap_compression import COMPRESSIONS
from .mcap_writer import DEFAULT_CHUNK_SIZE_BYTES, McapChunkedWriter
from .message_codec import message_encoder, plain_message
from .metadata import (
    CUSTOM_DATA_RECORD,
    EMPTY_BAG_STARTING_TIME_NS,
    METADATA_FILENAME,
    ROSBAG2_METADATA_RECORD,
    FileSummary,
    TopicSummary,
    build_bag_metadata,
    dump_metadata_yaml,
    dump_serialized_metadata,
    metadata_version_for_format,
    resolve_rosbag2_format,
    ros_distro_for_format,
)
from .qos import QosProfile, command_qos, serialize_qos_profiles

__all__ = [
    "BagWriter",
    "check_writable",
    "DEFAULT_MIN_FREE_BYTES",
    "library_identifier",
]

#: Free disk space required before a recording starts (64 MiB).
DEFAULT_MIN_FREE_BYTES = 64 * 1024 * 1024


def library_identifier() -> str:
    """MCAP header ``library`` string: ``dea_ros.bag <version> (mcap-python <version>)``."""
    try:
        mcap_version = version("mcap")
    except PackageNotFoundError:  # pragma: no cover
        mcap_version = "unknown"
    return f"dea_ros.bag {__version__} (rosbag2-compatible; mcap-python {mcap_version})"


def check_writable(path: str | Path, min_free_bytes: int = DEFAULT_MIN_FREE_BYTES) -> int:
    """Check that a bag directory can be created at ``path``; return the free bytes there.

    Raises :class:`BagError` naming the path and the fix when ``path`` already exists and is not
    an empty directory, when its nearest existing parent is not a writable directory (tested by
    creating and deleting a temporary file, so read-only mounts are caught even as root), or when
    that file system has less than ``min_free_bytes`` free.
    """
    path = Path(path).expanduser()
    if path.exists():
        if not path.is_dir():
            raise BagError(f"bag path {path} exists and is not a directory; choose a new bag directory")
        if any(path.iterdir()):
            raise BagError(
                f"bag directory {path} already exists and is not empty; rosbag2 never overwrites a "
                "bag: choose a new directory name"
            )
        probe_dir = path
    else:
        probe_dir = path.parent
        while not probe_dir.exists():
            if probe_dir == probe_dir.parent:
                break
            probe_dir = probe_dir.parent
        if not probe_dir.is_dir():
            raise BagError(
                f"cannot create bag directory {path}: {probe_dir} exists but is not a directory"
            )
    try:
        with tempfile.NamedTemporaryFile(dir=probe_dir, prefix=".dea_bag_probe_"):
            pass
    except OSError as exc:
        raise BagError(
            f"cannot write bag directory {path}: {probe_dir} is not writable "
            f"({exc.strerror or exc}); choose a writable location or fix its permissions"
        ) from exc
    free = shutil.disk_usage(probe_dir).free
    if free < min_free_bytes:
        raise BagError(
            f"not enough free disk space for bag {path}: {free / 2**20:.1f} MiB free on the file "
            f"system of {probe_dir}, {min_free_bytes / 2**20:.1f} MiB required; free some space or "
            "record to another disk"
        )
    return free


class _Topic:
    """Per-topic state of a :class:`BagWriter`."""

    __slots__ = ("name", "type_name", "qos", "channel_id", "type_hash", "count", "schema_text", "encoder")

    def __init__(self, name: str, type_name: str, qos: list[QosProfile], channel_id: int, type_hash: str,
                 schema_text: str) -> None:
        self.name = name
        self.type_name = type_name
        self.qos = qos
        self.channel_id = channel_id
        self.type_hash = type_hash
        self.count = 0
        self.schema_text = schema_text
        self.encoder: Callable[[Any], bytes] | None = None


class BagWriter:
    """Write a rosbag2-compatible MCAP bag directory (thread-safe; no ROS needed).

    * ``path``: bag directory to create (must not exist, or be empty).
    * ``compression``: chunk compression ``"zstd"`` (default), ``"lz4"`` or ``"none"``.
    * ``compression_level``: codec level, ``None`` for the codec default.
    * ``chunk_size_bytes``: uncompressed chunk size that closes a chunk (768 KiB as libmcap).
    * ``flush_period_s``: maximum age of unflushed messages, in seconds (``None``: flush only when
      a chunk is full and on close; not crash-safe).
    * ``fsync``: ``os.fsync`` on every flush (survive power loss, not only process death).
    * ``rosbag2_format``: ``"jazzy"`` (metadata version 9: Jazzy, Kilted, Rolling),
      ``"humble"`` (metadata version 5, readable by Humble and newer) or ``None``/``"auto"``:
      ``"humble"``, which every supported distro reads (:func:`~dea_ros.bag.metadata.default_rosbag2_format`).
    * ``ros_distro``: the distro recorded (``metadata.yaml`` v9; MCAP ``rosbag2`` record
      ``ROS_DISTRO`` for Humble, as Humble's storage plugin writes); default ``$ROS_DISTRO``,
      else the format's name (never empty).
    * ``custom_data``: ``custom_data`` key/value strings of ``metadata.yaml`` (v9; kept in the
      MCAP record ``rosbag2.custom_data`` for Humble).
    * ``definitions``: message definition source (default: a new :class:`MessageDefinitionStore`).
    * ``min_free_bytes``: free disk space required to start (see :func:`check_writable`).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        compression: str = "zstd",
        compression_level: int | None = None,
        chunk_size_bytes: int = DEFAULT_CHUNK_SIZE_BYTES,
        flush_period_s: float | None = 1.0,
        fsync: bool = False,
        rosbag2_format: str | None = None,
        ros_distro: str | None = None,
        custom_data: Mapping[str, str] | None = None,
        definitions: MessageDefinitionStore | None = None,
        min_free_bytes: int = DEFAULT_MIN_FREE_BYTES,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise BagError(f"compression={compression!r} is not supported; use one of {COMPRESSIONS}")
        if flush_period_s is not None and not flush_period_s > 0:
            raise BagError(f"flush_period_s={flush_period_s!r} must be > 0 s or None")
        self._format = resolve_rosbag2_format(rosbag2_format)
        self._version = metadata_version_for_format(self._format)
        self._path = Path(path).expanduser()
        check_writable(self._path, min_free_bytes)
        self._definitions = definitions if definitions is not None else MessageDefinitionStore()
        self._ros_distro = ros_distro_for_format(self._format, ros_distro)
        self._custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self._flush_period = flush_period_s
        self._fsync = fsync
        self._lock = threading.RLock()
        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[str, int] = {}
        self._closed = False
        self._flush_error: BagError | None = None
        self._pending_since: float | None = None
        name = self._path.name or "rosbag2"
        self._mcap_name = f"{name}_0.mcap"
        self._open_storage(compression, chunk_size_bytes, compression_level)
        self._stop_flusher = threading.Event()
        self._flusher: threading.Thread | None = None
        if flush_period_s is not None:
            self._flusher = threading.Thread(
                target=self._flush_loop, name=f"BagWriter flusher {self._path.name}", daemon=True
            )
            self._flusher.start()

    def _open_storage(self, compression: str, chunk_size_bytes: int, compression_level: int | None) -> None:
        """Create the ``.mcap`` file and write its Header and ``rosbag2`` records (flushed)."""
        try:
            self._path.mkdir(parents=True, exist_ok=True)
            # Unbuffered: every record/chunk the MCAP writer emits goes straight to the OS.
            self._file = open(self._path / self._mcap_name, "xb", buffering=0)
        except OSError as exc:
            raise BagError(f"cannot create bag file {self._path / self._mcap_name}: {exc.strerror or exc}") from exc
        try:
            self._mcap = McapChunkedWriter(
                self._file,
                profile="ros2",
                library=library_identifier(),
                compression=compression,
                chunk_size_bytes=chunk_size_bytes,
                compression_level=compression_level,
            )
            if self._version >= 8:
                self._mcap.add_metadata(
                    ROSBAG2_METADATA_RECORD,
                    {"serialized_metadata": dump_serialized_metadata(self._bag_info())},
                )
            else:
                # Humble's rosbag2_storage_mcap (MCAPStorage::ensure_rosdistro_metadata_added)
                # writes this record; Jazzy's read_metadata takes ROS_DISTRO from it.
                self._mcap.add_metadata(ROSBAG2_METADATA_RECORD, {"ROS_DISTRO": self._ros_distro})
                if self._custom_data:
                    self._mcap.add_metadata(CUSTOM_DATA_RECORD, dict(self._custom_data))
            self._mcap.flush(fsync=self._fsync)
        except BaseException:
            self._file.close()
            raise

    # -- properties --------------------------------------------------------------------------
    @property
    def path(self) -> Path:
        """The bag directory."""
        return self._path

    @property
    def mcap_path(self) -> Path:
        """The ``<dirname>_0.mcap`` storage file."""
        return self._path / self._mcap_name

    @property
    def rosbag2_format(self) -> str:
        """``"jazzy"`` or ``"humble"``: the format written."""
        return self._format

    @property
    def ros_distro(self) -> str:
        """The distro name recorded in the bag."""
        return self._ros_distro

    @property
    def metadata_version(self) -> int:
        """``metadata.yaml`` version written (9 for ``"jazzy"``, 5 for ``"humble"``)."""
        return self._version

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return self._mcap.message_count

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._closed

    def topic_message_counts(self) -> dict[str, int]:
        """``{topic: messages written}``."""
        with self._lock:
            return {name: topic.count for name, topic in self._topics.items()}

    # -- topics and messages -----------------------------------------------------------------
    def add_topic(
        self,
        name: str,
        type_name: str,
        qos: QosProfile | Sequence[QosProfile] | None = None,
        *,
        type_hash: str | None = None,
        schema_text: str | None = None,
    ) -> None:
        """Register a topic (MCAP schema + channel) before writing to it.

        * ``name``: absolute topic name, e.g. ``"/dea/voltage"``.
        * ``type_name``: ``pkg/msg/Type`` (``pkg/Type`` accepted).
        * ``qos``: offered QoS profile(s); default :func:`~dea_ros.bag.qos.command_qos`
          (reliable, volatile, keep_last 10). Use :func:`~dea_ros.bag.qos.sensor_data_qos` for
          best-effort sensor streams.
        * ``type_hash``: ``RIHS01_...`` to store; default from the installed type description.
        * ``schema_text``: the full ``ros2msg`` schema text to store (e.g. copied from another
          bag); default: built from the installed (else vendored) ``.msg`` files.

        Registering the same topic again with the same type and QoS is a no-op; anything else
        raises :class:`BagError`.
        """
        if not isinstance(name, str) or not name.startswith("/") or len(name) < 2:
            raise BagError(
                f"topic name {name!r} must be an absolute ROS name such as '/dea/voltage' "
                "(rosbag2 stores fully qualified names)"
            )
        canonical = normalize_type_name(type_name)
        profiles = _offered_profiles(name, qos)
        with self._lock:
            self._check_open()
            existing = self._topics.get(name)
            if existing is not None:
                if existing.type_name != canonical or existing.qos != profiles:
                    raise BagError(
                        f"topic {name} is already registered in {self.mcap_path} as "
                        f"{existing.type_name} with QoS {existing.qos}; a topic has one type and QoS"
                    )
                return
            self._add_channel_locked(name, canonical, profiles, type_hash, schema_text)

    def _add_channel_locked(self, name: str, canonical: str, profiles: list[QosProfile], type_hash: str | None,
                            schema_text: str | None) -> None:
        """Write the topic's schema (once per type) and channel records, flushed (lock held)."""
        if schema_text is None:
            definition = self._definitions.full_definition(canonical)
            text, encoding, known_hash = definition.text, definition.encoding, definition.type_hash
        else:
            text, encoding, known_hash = schema_text, "ros2msg", ""
        resolved_hash = known_hash if type_hash is None else type_hash
        if resolved_hash and not resolved_hash.startswith("RIHS01_"):
            raise BagError(f"type_hash {resolved_hash!r} of topic {name} must start with 'RIHS01_'")
        schema_id = self._schema_ids.get(canonical)
        if schema_id is None:
            schema_id = self._mcap.add_schema(canonical, encoding, text.encode("utf-8"))
            self._schema_ids[canonical] = schema_id
        channel_metadata = {"offered_qos_profiles": serialize_qos_profiles(profiles, self._version)}
        if resolved_hash:
            # Jazzy's MCAPStorage::create_topic writes it; Humble's reader ignores channel
            # metadata other than offered_qos_profiles, so Humble bags keep it too (lossless
            # conversion between the formats).
            channel_metadata["topic_type_hash"] = resolved_hash
        channel_id = self._mcap.add_channel(name, "cdr", schema_id, channel_metadata)
        self._topics[name] = _Topic(name, canonical, profiles, channel_id, resolved_hash, text)
        try:
            self._mcap.flush(fsync=self._fsync)
        except OSError as exc:
            raise self._poison(f"writing to {self.mcap_path} failed: {exc.strerror or exc}") from exc

    def write_serialized(
        self,
        topic: str,
        cdr_bytes: bytes | bytearray | memoryview,
        log_time_ns: int,
        publish_time_ns: int | None = None,
    ) -> None:
        """Write one CDR-serialized message (e.g. from ``rclpy.serialization.serialize_message``).

        * ``log_time_ns``: receive/record time, ns since the Unix epoch (rosbag2 ``recv_timestamp``).
        * ``publish_time_ns``: send time, ns (default ``log_time_ns``).
        """
        if not isinstance(cdr_bytes, (bytes, bytearray)):
            try:
                cdr_bytes = memoryview(cdr_bytes).tobytes()
            except TypeError:
                raise BagError(
                    f"cdr_bytes for topic {topic} must be bytes (e.g. from "
                    f"rclpy.serialization.serialize_message), got {type(cdr_bytes).__name__}"
                ) from None
        if len(cdr_bytes) < 4 or cdr_bytes[0] != 0:
            raise BagError(
                f"cdr_bytes for topic {topic} do not start with a CDR encapsulation header "
                f"(00 01 00 00 for little-endian CDR): {bytes(cdr_bytes[:4]).hex(' ') or 'empty'}"
            )
        log_time = _timestamp(log_time_ns, "log_time_ns")
        publish_time = log_time if publish_time_ns is None else _timestamp(publish_time_ns, "publish_time_ns")
        with self._lock:
            if self._closed or self._flush_error is not None:
                self._check_open()
            entry = self._topics.get(topic)
            if entry is None:
                raise BagError(
                    f"topic {topic!r} is not registered in {self.mcap_path}; call "
                    f"add_topic({topic!r}, 'pkg/msg/Type') first"
                )
            try:
                self._mcap.add_message(entry.channel_id, log_time, publish_time, cdr_bytes, entry.count + 1)
                entry.count += 1
                now = time.monotonic()
                if self._pending_since is None:
                    self._pending_since = now
                elif self._flush_period is not None and now - self._pending_since >= self._flush_period:
                    self._flush_locked()
                if self._mcap.pending_messages == 0:
                    self._pending_since = None
            except OSError as exc:
                raise self._poison(f"writing to {self.mcap_path} failed: {exc.strerror or exc}") from exc

    def write(
        self,
        topic: str,
        message: Any,
        log_time_ns: int,
        publish_time_ns: int | None = None,
    ) -> None:
        """Serialize ``message`` (dict or object with the type's fields) to CDR and write it.

        Serialization uses mcap_ros2's dynamic CDR encoder built from the topic's schema text;
        missing fields take their default (0, "", empty). Nested messages may be dicts too, e.g.
        ``{"header": {"stamp": {"sec": 1, "nanosec": 0}, "frame_id": "x"}, "range": 0.01}``.
        ``byte`` fields take ints in dicts; rclpy message objects are accepted as well (their
        ``bytes`` values of ``byte`` fields are converted), although in a node
        ``write_serialized(topic, rclpy.serialization.serialize_message(msg), t)`` is faster.
        """
        with self._lock:
            entry = self._topics.get(topic)
            if entry is None:
                self._check_open()
                raise BagError(
                    f"topic {topic!r} is not registered in {self.mcap_path}; call "
                    f"add_topic({topic!r}, 'pkg/msg/Type') first"
                )
            encoder = entry.encoder
            if encoder is None:
                encoder = entry.encoder = message_encoder(entry.type_name, entry.schema_text)
        try:
            data = encoder(plain_message(message))
        except Exception as exc:
            raise BagError(
                f"cannot serialize message for topic {topic} ({entry.type_name}): "
                f"{type(exc).__name__}: {exc}"
            ) from exc
        self.write_serialized(topic, data, log_time_ns, publish_time_ns)

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Add an MCAP Metadata record (e.g. the experiment protocol) as ``{str: str}``.

        The name ``"rosbag2"`` is reserved for the bag information rosbag2 stores itself.
        """
        if not isinstance(name, str) or not name:
            raise BagError(f"metadata name must be a non-empty string, got {name!r}")
        if name in (ROSBAG2_METADATA_RECORD, CUSTOM_DATA_RECORD):
            raise BagError(f"metadata name {name!r} is reserved for rosbag2's bag information; choose another")
        if not isinstance(data, Mapping):
            raise BagError(f"metadata {name!r} must be a mapping of str to str, got {type(data).__name__}")
        bad = [k for k, v in data.items() if not isinstance(k, str) or not isinstance(v, str)]
        if bad:
            raise BagError(
                f"metadata {name!r}: keys and values must be str (convert numbers with str() or "
                f"json.dumps); offending keys: {bad!r}"
            )
        with self._lock:
            self._check_open()
            try:
                self._mcap.add_metadata(name, data)
                self._mcap.flush(fsync=self._fsync)
            except OSError as exc:
                raise self._poison(f"writing to {self.mcap_path} failed: {exc.strerror or exc}") from exc

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS now (``fsync`` if configured)."""
        with self._lock:
            self._check_open()
            self._flush_locked()

    def close(self) -> Path:
        """Finish the MCAP file (summary, footer) and write ``metadata.yaml``; return the bag dir.

        Idempotent. After a failure to finish, the partial file can still be recovered with
        :func:`dea_ros.bag.recover_bag`. After a write error nothing more is written (the file
        may end inside a record): the file is closed and :class:`BagError` raised; recover it.
        """
        with self._lock:
            if self._closed:
                return self._path
            self._closed = True
        self._stop_flusher.set()
        if self._flusher is not None:
            self._flusher.join()
        with self._lock:
            if self._flush_error is not None:
                self._file.close()
                raise BagError(
                    f"{self._flush_error}; the bag was closed unfinished: run "
                    f"dea_ros.bag.recover_bag({str(self._path)!r}) to salvage the recorded data"
                )
            try:
                info = self._bag_info()
                if self._version >= 8:
                    self._mcap.add_metadata(
                        ROSBAG2_METADATA_RECORD, {"serialized_metadata": dump_serialized_metadata(info)}
                    )
                self._mcap.finish()
                if self._fsync:
                    os.fsync(self._file.fileno())
            except OSError as exc:
                raise BagError(
                    f"finishing {self.mcap_path} failed: {exc.strerror or exc}; run "
                    f"dea_ros.bag.recover_bag({str(self._path)!r}) to salvage the recorded data"
                ) from exc
            finally:
                self._file.close()
            write_text_atomic(self._path / METADATA_FILENAME, dump_metadata_yaml(info), self._fsync)
        return self._path

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        self.close()

    # -- internals ---------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f"bag {self._path} is closed; open a new BagWriter to record more")
        if self._flush_error is not None:
            # a new exception each time: re-raising one object grows its traceback without end
            raise BagError(f"{self._flush_error} (an earlier write failed; nothing more is written)")

    def _poison(self, message: str) -> BagError:
        """After a write error the file may end inside a record: refuse every later write."""
        error = BagError(message)
        if self._flush_error is None:
            self._flush_error = error
        return error

    def _flush_locked(self) -> None:
        try:
            self._mcap.flush(fsync=self._fsync)
        except OSError as exc:
            raise self._poison(f"flushing {self.mcap_path} failed: {exc.strerror or exc}") from exc
        self._pending_since = None

    def _flush_loop(self) -> None:
        assert self._flush_period is not None
        tick = self._flush_period / 4.0
        while not self._stop_flusher.wait(tick):
            with self._lock:
                if self._closed:
                    return
                since = self._pending_since
                if since is not None and time.monotonic() - since >= 0.75 * self._flush_period:
                    try:
                        self._flush_locked()
                    except BagError:
                        return  # poisoned: raised in the recording thread by its next write/flush

    def _bag_info(self) -> dict[str, Any]:
        """The bag's ``metadata.yaml`` mapping as written so far."""
        count = self._mcap.message_count
        if count:
            start, end = self._mcap.message_start_time, self._mcap.message_end_time
            file_summary = FileSummary(self._mcap_name, start, end - start, count)
        else:
            file_summary = FileSummary(self._mcap_name, EMPTY_BAG_STARTING_TIME_NS, 0, 0)
        topics = [
            TopicSummary(t.name, t.type_name, t.count, t.qos, t.type_hash) for t in self._topics.values()
        ]
        return build_bag_metadata(
            version=self._version,
            files=[file_summary],
            topics=topics,
            custom_data=self._custom_data,
            ros_distro=self._ros_distro,
        )


def _offered_profiles(topic: str, qos: QosProfile | Sequence[QosProfile] | None) -> list[QosProfile]:
    """The list of offered QoS profiles of ``add_topic`` (default: :func:`~dea_ros.bag.qos.command_qos`)."""
    if qos is None:
        return [command_qos()]
    if isinstance(qos, QosProfile):
        return [qos]
    profiles = list(qos)
    if not all(isinstance(p, QosProfile) for p in profiles):
        raise BagError(f"qos of topic {topic}: expected QosProfile or a list of them, got {qos!r}")
    return profiles


def _timestamp(value: Any, name: str) -> int:
    """A timestamp argument as an integer number of ns in [0, 2**64), else :class:`BagError`."""
    try:
        integer = int(value)
    except (TypeError, ValueError):
        raise BagError(f"{name}={value!r} must be an integer number of nanoseconds") from None
    if integer != value or not 0 <= integer < 2**64:
        raise BagError(f"{name}={value!r} must be an integer in [0, 2**64) nanoseconds")
    return integer
