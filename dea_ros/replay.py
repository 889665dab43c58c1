"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.nodes.replay_node."""
from .nodes.replay_node import cmd_replay, message_class, playback_qos, register, replay

__all__ = ["register", "replay", "cmd_replay", "message_class", "playback_qos"]
