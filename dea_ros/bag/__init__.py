"""rosbag2-compatible MCAP bags, written and read without ROS (no rclpy import anywhere here).

Quick start
===========

Record (in a node, from a script or a notebook)::

    from dea_ros.bag import BagWriter, BagReader, sensor_data_qos

    with BagWriter("runs/2024-05-01_sine_3kV", flush_period_s=1.0) as bag:
        bag.add_topic("/dea/range", "sensor_msgs/msg/Range", sensor_data_qos())   # best_effort, depth 5
        bag.add_topic("/dea/voltage_cmd", "std_msgs/msg/Float64")                 # reliable, depth 10
        bag.add_metadata("protocol", {"waveform": "sine", "amplitude_V": "3000"})
        bag.write_serialized("/dea/range", rclpy.serialization.serialize_message(msg), t_ns)
        bag.write("/dea/voltage_cmd", {"data": 1500.0}, t_ns)      # dict -> CDR via mcap_ros2

Read back (log-time order, decoded with the schema stored in the bag)::

    with BagReader("runs/2024-05-01_sine_3kV") as bag:
        bag.require_topics({"/dea/range": "sensor_msgs/msg/Range"})
        for topic, t_ns, msg in bag.messages(["/dea/range"]):
            print(t_ns, msg.range)

Before a recording, ``check_writable(dir, min_free_bytes)`` fails early for an existing or
unwritable directory or a full disk. After the recorder was killed, ``recover_bag(dir)`` rewrites
the unfinished ``.mcap`` (everything older than ``flush_period_s`` survives) and regenerates
``metadata.yaml``; ``BagReader`` can also read the unfinished file directly (with a warning).

On-disk format (what ``ros2 bag record -s mcap -o <dir>`` writes)
================================================================

* ``<dir>/<dirname>_0.mcap`` and ``<dir>/metadata.yaml`` (written on close).
* MCAP header profile ``ros2``, library ``dea_ros.bag <version> (...)``; chunked, zstd (or lz4 /
  none); chunk CRCs, message indexes, summary with statistics/chunk/metadata indexes.
* One schema per type: name ``pkg/msg/Type``, encoding ``ros2msg``, data = the ``.msg`` text with
  dependencies appended after 80 ``=`` and ``MSG: pkg/Type`` lines (rosbag2's
  ``LocalMessageDefinitionSource``). Texts come from installed ROS share dirs, else are vendored.
* One channel per topic: message encoding ``cdr``, metadata ``offered_qos_profiles`` (YAML text
  of the profile list) and ``topic_type_hash`` (``RIHS01_...``; omitted when unknown).
* MCAP Metadata record ``rosbag2`` with ``serialized_metadata`` (the bag information, written on
  open and on close like rosbag2_storage_mcap), plus the records added with ``add_metadata``.
* ``rosbag2_format="jazzy"``: metadata version 9 with string QoS policies (``keep_last``,
  ``reliable``, ``best_effort``, ``volatile`` ...) -> Jazzy, Kilted, Rolling.
  ``rosbag2_format="humble"``: metadata version 5 with integer QoS enums in a YAML string, no
  ``type_description_hash``/``custom_data``/``ros_distro`` fields, an MCAP ``rosbag2`` record
  ``{ROS_DISTRO: ...}`` as Humble's storage plugin writes -> readable by Humble and every newer
  distro (Humble's reader rejects version 9 metadata). Default (``None``/``"auto"``): humble,
  the format every supported distro reads, whatever ``$ROS_DISTRO`` says. ``convert_bag(dir, "humble")`` (CLI
  ``dea-ros bag convert DIR --to humble``) rewrites a bag in the other format, losslessly.
  ``docs/rosbag2_formats.md`` lists what each distro's parser requires and how it was checked.
* Timestamps: ``log_time`` = receive/record time (rosbag2 ``recv_timestamp``), ``publish_time``
  = send time (defaults to log time), both integer ns since the Unix epoch.

Opening the bags with ROS tools
===============================

* ``ros2 bag info <dir>`` and ``ros2 bag play <dir>`` (Humble or newer with the MCAP storage
  plugin: ``sudo apt install ros-$ROS_DISTRO-rosbag2-storage-mcap``; it is the default storage
  from Iron on; on Humble add ``-s mcap`` if auto-detection fails). Record Humble-playable bags
  with ``BagWriter(..., rosbag2_format="humble")`` (the default) or
  convert them afterwards. Playback re-offers the recorded QoS.
* Foxglove Studio / Foxglove app: open ``<dir>/<dirname>_0.mcap`` (File > Open local file); the
  ``ros2msg`` schemas in the file decode everything without a ROS installation.
* PlotJuggler: load ``<dir>/<dirname>_0.mcap`` with the MCAP data loader (PlotJuggler >= 3.6 ships
  it), or open ``<dir>/metadata.yaml`` with the ROS 2 bag loader of the ``plotjuggler_ros`` plugin
  (needs ROS sourced and rosbag2_storage_mcap).
* Python without ROS: this module, ``rosbags`` (``rosbags.rosbag2.Reader(<dir>)``) or ``mcap`` +
  ``mcap_ros2`` on the ``.mcap`` file.
* A killed recording: run ``python -c "from dea_ros.bag import recover_bag; recover_bag('<dir>')"``
  first (``ros2 bag reindex`` cannot repair a file without footer).

Modules (one concept each; imports point down this list, from the bag API to the MCAP records)
=============================================================================================

Bags (rosbag2 directories):

* ``writer``: :class:`BagWriter`, :func:`check_writable`, the rosbag2 Metadata record names.
* ``reader``: :class:`BagReader` (summary-based for complete files, scan-based for truncated ones).
* ``recover``: :func:`recover_bag` and its :class:`RecoveryReport`.
* ``convert``: :func:`convert_bag` (Humble <-> Jazzy format).
* ``playback``: a bag's messages on their original schedule (for ``dea-ros replay``).

What a bag stores besides messages:

* ``metadata``: ``metadata.yaml`` (build, dump, load, validate; format <-> version).
* ``qos``: QoS profiles as rosbag2 stores them.
* ``definitions``: message definitions (``ros2msg`` schema texts) and type hashes.
* ``vendored_messages``: the ``.msg`` texts used when no ROS installation provides them.
* ``message_codec``: CDR encoding/decoding from a bag's schema text.
* ``files``: atomic text files, directory fsync, disk-full errors.

MCAP files (no ROS, no rosbag2 conventions):

* ``mcap_writer``: the chunked writer (flush on demand; resume an unfinished file).
* ``mcap_scan``: :func:`~dea_ros.bag.mcap_scan.scan_mcap`, the record-by-record scan of a
  possibly truncated or damaged file.
* ``mcap_summary_check``: the summary section and footer checked against the scanned data.
* ``mcap_finish``: finishing an unfinished file where it lies (full disk).
* ``mcap_contents``: :class:`~dea_ros.bag.mcap_contents.McapScan` and ``ChunkInfo``, what a scan found.
* ``mcap_records``: the record format: constants, parsing of one record and of a chunk's content.
* ``mcap_compression``: chunk compression (zstd, lz4, none).

The bag errors and warnings are in :mod:`dea_ros.errors`; turning a bag's signals into
experiments is :mod:`dea_ros.identify.bag_experiments`; the ``dea-ros bag`` command is
:mod:`dea_ros.cli.bag`.
"""
from __future__ import annotations

from ..errors import BagError, BagTruncatedWarning, BagWarning
from .convert import convert_bag
from .definitions import MessageDefinition, MessageDefinitionStore, default_search_prefixes
from .metadata import default_rosbag2_format, resolve_rosbag2_format
from .playback import BagPlayback, open_playback, playback_schedule
from .qos import (
    INFINITE_DURATION,
    QosDuration,
    QosProfile,
    command_qos,
    parse_qos_profiles,
    qos_from_dict,
    qos_to_dict,
    sensor_data_qos,
    serialize_qos_profiles,
)
from .reader import BagMessage, BagReader, RawBagMessage, TopicInfo
from .recover import RecoveryReport, recover_bag
from .writer import DEFAULT_MIN_FREE_BYTES, BagWriter, check_writable

__all__ = [
    "BagWriter",
    "BagPlayback",
    "open_playback",
    "playback_schedule",
    "BagReader",
    "BagMessage",
    "RawBagMessage",
    "TopicInfo",
    "check_writable",
    "recover_bag",
    "convert_bag",
    "default_rosbag2_format",
    "resolve_rosbag2_format",
    "RecoveryReport",
    "DEFAULT_MIN_FREE_BYTES",
    "BagError",
    "BagWarning",
    "BagTruncatedWarning",
    "QosProfile",
    "QosDuration",
    "INFINITE_DURATION",
    "command_qos",
    "sensor_data_qos",
    "qos_to_dict",
    "qos_from_dict",
    "serialize_qos_profiles",
    "parse_qos_profiles",
    "MessageDefinition",
    "MessageDefinitionStore",
    "default_search_prefixes",
]
