"""Device protocols and safety: amplifier safety controller and backends, ILD1320 laser protocol,
serial backend and emulator. No ROS import."""
