"""dea_ros: model, fast identification and ROS 2 nodes for a mass-loaded dielectric elastomer actuator.

The core (``dea_ros.model``, ``dea_ros.solvers``, ``dea_ros.identify``, ``dea_ros.bag``,
``dea_ros.hardware``) imports no ROS; the nodes in ``dea_ros.nodes`` are thin rclpy layers.
"""
__version__ = "0.1.0"
