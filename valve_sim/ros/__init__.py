"""ROS 2 adapters: valve_node, analyser_node and their helpers.

Lives here: the nodes, parameter descriptors from specs, diagnostics, spinning.
The home of rclpy; nodes stay thin around valve_sim.core and valve_sim.analysis.
May import: valve_sim.core, valve_sim.analysis, valve_sim.recording, rclpy.
"""
