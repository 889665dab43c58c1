"""The ROS 2 nodes: thin rclpy adapters over the core, one node per module, each with a ``main()``.

Nodes convert messages to core calls and back and own timers, parameters, QoS and lifecycle;
what they compute is a call into the core (:mod:`dea_ros.control`, :mod:`dea_ros.hardware`,
:mod:`dea_ros.identify`, :mod:`dea_ros.bag`, :mod:`dea_ros.solvers`):

* :mod:`.amplifier_node` -- the high-voltage amplifier (lifecycle, safety core, backends);
* :mod:`.laser_sensor_node` -- the ILD1320 laser head (``displacement``);
* :mod:`.model_node` -- the displacement predicted from the applied voltage;
* :mod:`.position_controller_node` -- position control (lifecycle);
* :mod:`.identifier_node` -- runs a protocol, records a bag, identifies offline;
* :mod:`.mock_hardware_node` -- the simulated rig;
* :mod:`.replay_node` -- ``dea-ros replay``: a bag republished with its timing.

:mod:`.common` holds the topic names, QoS profiles and message helpers, :mod:`.runner` the
spinning and signal handling. Nothing else is imported here (importing a node module imports
rclpy): one BLAS thread per process unless the environment says otherwise, set before numpy is
imported (:mod:`dea_ros.blas_threads`; the identification in identifier_node, issue 22).
"""
from ..blas_threads import use_one_blas_thread

use_one_blas_thread()

__all__: list = []
