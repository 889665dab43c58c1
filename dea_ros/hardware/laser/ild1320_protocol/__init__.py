"""Micro-Epsilon optoNCDT 1320 (ILD1320) RS422 protocol -- pure, no I/O.

Nothing here touches a port or a clock; the serial backend
(:mod:`dea_ros.hardware.laser.ild1320_serial`) and the emulator
(:mod:`dea_ros.sim.ild1320_emulator`) are built on it.

* :mod:`.frames`: the binary measurement stream (serial settings, the three-byte frames, the
  18-bit codes, distances in metres, error codes, mastering) and the incremental
  :class:`FrameDecoder` that resynchronises on corrupted streams;
* :mod:`.commands`: the ASCII commands and replies (formatting, parsing, measuring rates);
* :mod:`.settings`: what the connected sensor reports against what the configuration expects,
  and the known state the backend sets on every connect (:func:`check_laser_sensor`).

Protocol facts and where they come from
---------------------------------------
Sources: the optoNCDT 1320 operating instructions (ILD1320 manual) and, where the
1320 pages could not be found, the optoNCDT 1420 / 1220 manuals of the same
sensor family, which share the interface chapter and the ASCII appendix. Each module
states its facts with the chapter they come from; **unverified** marks what no page
confirmed.
"""
from .commands import (
    ADDITIONAL_OUTPUTS,
    ALLOWED_MEASURING_RATES_HZ,
    COMMAND_TERMINATOR,
    PROMPT,
    CommandError,
    CommandReply,
    SensorInfo,
    command_bytes,
    find_reply_end,
    format_rate_khz,
    getinfo_command,
    laser_command,
    mastermv_command,
    measrate_command,
    outadd_rs422_command,
    outhold_command,
    output_command,
    parse_command_line,
    parse_getinfo_reply,
    parse_laser_reply,
    parse_mastermv_reply,
    parse_measrate_reply,
    parse_measrate_value_hz,
    parse_outadd_rs422_reply,
    parse_outhold_reply,
    parse_output_reply,
    parse_reply,
    render_error,
    render_reply,
    validate_measuring_rate_hz,
)
from .frames import (
    BYTES_PER_VALUE,
    DEFAULT_BAUDRATE,
    DEFAULT_MEASURING_RANGE_M,
    DISTANCE_CODE_MAX,
    EMR_CODE,
    ERROR_CODES,
    FLAG_H,
    FLAG_H_ADDITIONAL,
    FLAG_L,
    FLAG_M,
    MAX_RAW_CODE,
    OUTPUT_DELAY_CYCLES,
    SERIAL_BYTESIZE,
    SERIAL_PARITY,
    SERIAL_STOPBITS,
    SMR_CODE,
    FrameDecoder,
    FrameFormatError,
    Sample,
    apply_tare,
    code_to_displacement_m,
    decode_frame,
    displacement_to_code,
    encode_displacement,
    encode_value,
    error_to_code,
    mastered_displacement_to_code,
    quantum_m,
)
from .settings import (
    KNOWN_STATE,
    MODEL_PREFIX,
    LaserSensorExpectation,
    LaserSensorReport,
    LaserSensorSettings,
    check_laser_sensor,
)

__all__ = [
    # frames
    "DEFAULT_BAUDRATE", "SERIAL_BYTESIZE", "SERIAL_PARITY", "SERIAL_STOPBITS", "BYTES_PER_VALUE", "FLAG_L",
    "FLAG_M", "FLAG_H", "FLAG_H_ADDITIONAL", "MAX_RAW_CODE", "DISTANCE_CODE_MAX", "SMR_CODE", "EMR_CODE",
    "DEFAULT_MEASURING_RANGE_M", "ERROR_CODES", "OUTPUT_DELAY_CYCLES", "FrameFormatError", "Sample",
    "encode_value", "decode_frame", "quantum_m", "code_to_displacement_m", "displacement_to_code",
    "error_to_code", "encode_displacement", "mastered_displacement_to_code", "apply_tare", "FrameDecoder",
    # commands
    "ALLOWED_MEASURING_RATES_HZ", "ADDITIONAL_OUTPUTS", "PROMPT", "COMMAND_TERMINATOR", "CommandError",
    "CommandReply", "SensorInfo", "command_bytes", "parse_command_line", "validate_measuring_rate_hz",
    "format_rate_khz", "getinfo_command", "measrate_command", "laser_command", "output_command",
    "mastermv_command", "outadd_rs422_command", "outhold_command", "find_reply_end", "parse_reply",
    "render_reply", "render_error", "parse_getinfo_reply", "parse_measrate_value_hz", "parse_measrate_reply",
    "parse_laser_reply", "parse_output_reply", "parse_mastermv_reply", "parse_outadd_rs422_reply",
    "parse_outhold_reply",
    # the connected sensor against the configuration
    "MODEL_PREFIX", "KNOWN_STATE", "LaserSensorSettings", "LaserSensorExpectation", "LaserSensorReport",
    "check_laser_sensor",
]
