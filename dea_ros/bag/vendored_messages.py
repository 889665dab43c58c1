"""Vendored ROS 2 ``.msg`` definitions, used when no ROS share directory provides them.

The texts are byte-for-byte copies of the ``share/<pkg>/msg/<Type>.msg`` files of ROS 2 Kilted
(std_msgs / sensor_msgs / diagnostic_msgs 5.5.1, builtin_interfaces / rosgraph_msgs 2.3.0), so a
bag written without ROS carries the same schema text as one written by ``ros2 bag record``.
They are a fallback only: when a ROS installation (apt or the PyPI wheels) provides the
definitions, its own texts are recorded (they differ between distros: Humble's Range has no
``variance``, and its comments differ). Only the types the DEA rig publishes are included; other types
need a ROS installation (or an
explicit ``extra_definitions`` mapping passed to :class:`~dea_ros.bag.definitions.MessageDefinitionStore`).
"""
from __future__ import annotations

from types import MappingProxyType

__all__ = ["VENDORED_MSG_TEXTS", "VENDORED_PACKAGE_VERSIONS"]

#: Package versions the texts were copied from (ROS 2 Kilted); tests compare them byte for byte
#: with installed files only when the installed package has this version.
VENDORED_PACKAGE_VERSIONS = MappingProxyType({
    "std_msgs": "5.5.1",
    "sensor_msgs": "5.5.1",
    "diagnostic_msgs": "5.5.1",
    "builtin_interfaces": "2.3.0",
    "rosgraph_msgs": "2.3.0",
})

_TEXTS = {
    "builtin_interfaces/msg/Time": (
        '# This message communicates ROS Time defined here:\n'
        '# https://design.ros2.org/articles/clock_and_time.html\n'
        '\n'
        '# The seconds component, valid over all int32 values.\n'
        'int32 sec\n'
        '\n'
        '# The nanoseconds component, valid in the range [0, 1e9).\n'
        'uint32 nanosec\n'
    ),
    "std_msgs/msg/Header": (
        '# Standard metadata for higher-level stamped data types.\n'
        '# This is generally used to communicate timestamped data\n'
        '# in a particular coordinate frame.\n'
        '\n'
        '# Two-integer timestamp that is expressed as seconds and nanoseconds.\n'
        'builtin_interfaces/Time stamp\n'
        '\n'
        '# Transform frame with which this data is associated.\n'
        'string frame_id\n'
    ),
    "std_msgs/msg/Float64": (
        '# This was originally provided as an example message.\n'
        '# It is deprecated as of Foxy\n'
        '# It is recommended to create your own semantically meaningful message.\n'
        '# However if you would like to continue using this please use the equivalent in example_msgs.\n'
        '\n'
        'float64 data\n'
    ),
    "std_msgs/msg/String": (
        '# This was originally provided as an example message.\n'
        '# It is deprecated as of Foxy\n'
        '# It is recommended to create your own semantically meaningful message.\n'
        '# However if you would like to continue using this please use the equivalent in example_msgs.\n'
        '\n'
        'string data\n'
    ),
    "sensor_msgs/msg/Range": (
        '# Single range reading from an active ranger that emits energy and reports\n'
        '# one range reading that is valid along an arc at the distance measured.\n'
        '# This message is  not appropriate for laser scanners. See the LaserScan\n'
        '# message if you are working with a laser scanner.\n'
        '#\n'
        '# This message also can represent a fixed-distance (binary) ranger.  This\n'
        '# sensor will have min_range===max_range===distance of detection.\n'
        '# These sensors follow REP 117 and will output -Inf if the object is detected\n'
        '# and +Inf if the object is outside of the detection range.\n'
        '\n'
        'std_msgs/Header header # timestamp in the header is the time the ranger\n'
        '                             # returned the distance reading\n'
        '\n'
        '# Radiation type enums\n'
        '# If you want a value added to this list, send an email to the ros-users list\n'
        'uint8 ULTRASOUND=0\n'
        'uint8 INFRARED=1\n'
        '\n'
        'uint8 radiation_type    # the type of radiation used by the sensor\n'
        '                        # (sound, IR, etc) [enum]\n'
        '\n'
        'float32 field_of_view   # the size of the arc that the distance reading is\n'
        '                        # valid for [rad]\n'
        '                        # the object causing the range reading may have\n'
        '                        # been anywhere within -field_of_view/2 and\n'
        '                        # field_of_view/2 at the measured range.\n'
        '                        # 0 angle corresponds to the x-axis of the sensor.\n'
        '\n'
        'float32 min_range       # minimum range value [m]\n'
        'float32 max_range       # maximum range value [m]\n'
        '                        # Fixed distance rangers require min_range==max_range\n'
        '\n'
        'float32 range           # range data [m]\n'
        '                        # (Note: values < range_min or > range_max should be discarded)\n'
        '                        # Fixed distance rangers only output -Inf or +Inf.\n'
        '                        # -Inf represents a detection within fixed distance.\n'
        '                        # (Detection too close to the sensor to quantify)\n'
        '                        # +Inf represents no detection within the fixed distance.\n'
        '                        # (Object out of range)\n'
        '\n'
        'float32 variance        # variance of the range sensor\n'
        '                        # 0 is interpreted as variance unknown\n'
    ),
    "sensor_msgs/msg/BatteryState": (
        '\n'
        '# Constants are chosen to match the enums in the linux kernel\n'
        '# defined in include/linux/power_supply.h as of version 3.7\n'
        '# The one difference is for style reasons the constants are\n'
        '# all uppercase not mixed case.\n'
        '\n'
        '# Power supply status constants\n'
        'uint8 POWER_SUPPLY_STATUS_UNKNOWN = 0\n'
        'uint8 POWER_SUPPLY_STATUS_CHARGING = 1\n'
        'uint8 POWER_SUPPLY_STATUS_DISCHARGING = 2\n'
        'uint8 POWER_SUPPLY_STATUS_NOT_CHARGING = 3\n'
        'uint8 POWER_SUPPLY_STATUS_FULL = 4\n'
        '\n'
        '# Power supply health constants\n'
        'uint8 POWER_SUPPLY_HEALTH_UNKNOWN = 0\n'
        'uint8 POWER_SUPPLY_HEALTH_GOOD = 1\n'
        'uint8 POWER_SUPPLY_HEALTH_OVERHEAT = 2\n'
        'uint8 POWER_SUPPLY_HEALTH_DEAD = 3\n'
        'uint8 POWER_SUPPLY_HEALTH_OVERVOLTAGE = 4\n'
        'uint8 POWER_SUPPLY_HEALTH_UNSPEC_FAILURE = 5\n'
        'uint8 POWER_SUPPLY_HEALTH_COLD = 6\n'
        'uint8 POWER_SUPPLY_HEALTH_WATCHDOG_TIMER_EXPIRE = 7\n'
        'uint8 POWER_SUPPLY_HEALTH_SAFETY_TIMER_EXPIRE = 8\n'
        '\n'
        '# Power supply technology (chemistry) constants\n'
        'uint8 POWER_SUPPLY_TECHNOLOGY_UNKNOWN = 0 # Unknown battery technology\n'
        'uint8 POWER_SUPPLY_TECHNOLOGY_NIMH = 1    # Nickel-Metal Hydride battery\n'
        'uint8 POWER_SUPPLY_TECHNOLOGY_LION = 2    # Lithium-ion battery\n'
        'uint8 POWER_SUPPLY_TECHNOLOGY_LIPO = 3    # Lithium Polymer battery\n'
        'uint8 POWER_SUPPLY_TECHNOLOGY_LIFE = 4    # Lithium Iron Phosphate battery\n'
        'uint8 POWER_SUPPLY_TECHNOLOGY_NICD = 5    # Nickel-Cadmium battery\n'
        'uint8 POWER_SUPPLY_TECHNOLOGY_LIMN = 6    # Lithium Manganese Dioxide battery\n'
        'uint8 POWER_SUPPLY_TECHNOLOGY_TERNARY = 7 # Ternary Lithium battery\n'
        'uint8 POWER_SUPPLY_TECHNOLOGY_VRLA = 8    # Valve Regulated Lead-Acid battery\n'
        '\n'
        'std_msgs/Header  header\n'
        'float32 voltage          # Voltage in Volts (Mandatory)\n'
        'float32 temperature      # Temperature in Degrees Celsius (If unmeasured NaN)\n'
        'float32 current          # Negative when discharging (A)  (If unmeasured NaN)\n'
        'float32 charge           # Current charge in Ah  (If unmeasured NaN)\n'
        'float32 capacity         # Capacity in Ah (last full capacity)  (If unmeasured NaN)\n'
        'float32 design_capacity  # Capacity in Ah (design capacity)  (If unmeasured NaN)\n'
        'float32 percentage       # Charge percentage on 0 to 1 range  (If unmeasured NaN)\n'
        'uint8   power_supply_status     # The charging status as reported. Values defined above\n'
        'uint8   power_supply_health     # The battery health metric. Values defined above\n'
        'uint8   power_supply_technology # The battery chemistry. Values defined above\n'
        'bool    present          # True if the battery is present\n'
        '\n'
        'float32[] cell_voltage   # An array of individual cell voltages for each cell in the pack\n'
        '                         # If individual voltages unknown but number of cells known set each to NaN\n'
        'float32[] cell_temperature # An array of individual cell temperatures for each cell in the pack\n'
        '                           # If individual temperatures unknown but number of cells known set each to NaN\n'
        'string location          # The location into which the battery is inserted. (slot number or plug)\n'
        'string serial_number     # The best approximation of the battery serial number\n'
    ),
    "rosgraph_msgs/msg/Clock": (
        '# This message communicates the current time.\n'
        '#\n'
        '# For more information, see https://design.ros2.org/articles/clock_and_time.html.\n'
        'builtin_interfaces/Time clock\n'
    ),
    "diagnostic_msgs/msg/DiagnosticArray": (
        '# This message is used to send diagnostic information about the state of the robot.\n'
        'std_msgs/Header header # for timestamp\n'
        'DiagnosticStatus[] status # an array of components being reported on\n'
    ),
    "diagnostic_msgs/msg/DiagnosticStatus": (
        '# This message holds the status of an individual component of the robot.\n'
        '\n'
        '# Possible levels of operations.\n'
        'byte OK=0\n'
        'byte WARN=1\n'
        'byte ERROR=2\n'
        'byte STALE=3\n'
        '\n'
        '# Level of operation enumerated above.\n'
        'byte level\n'
        '# A description of the test/component reporting.\n'
        'string name\n'
        '# A description of the status.\n'
        'string message\n'
        '# A hardware unique string.\n'
        'string hardware_id\n'
        '# An array of values associated with the status.\n'
        'KeyValue[] values\n'
        '\n'
    ),
    "diagnostic_msgs/msg/KeyValue": (
        '# What to label this value when viewing.\n'
        'string key\n'
        '# A value to track over time.\n'
        'string value\n'
    ),
}

#: Read-only ``{"pkg/msg/Type": msg_text}`` mapping.
VENDORED_MSG_TEXTS = MappingProxyType(_TEXTS)
