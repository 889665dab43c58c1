"""The simulated rig (no ROS): what mock_hardware_node and the closed-loop simulation run."""
