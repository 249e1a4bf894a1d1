"""valve_sim: a virtual direct-pressure-sensing water-hydraulic relief valve for ROS 2 test benches.

The package is built in wings, each importing only the wings below it:

    core       the model: parameters, Eqs. (1)-(16), integrator, steady state (numpy, scipy)
    analysis   step-response measures, signal handling, reference data, plots
    recording  MCAP bags as rosbag2 writes them, CDR tick messages, replay
    ros        the nodes (valve_node, analyser_node): thin rclpy adapters
    commands   the `valve-sim` command line, one module per subcommand

test/test_layering.py keeps it so.
"""

__version__ = '0.1.0'
