"""valve_sim: a virtual direct-pressure-sensing water-hydraulic relief valve for ROS 2 test benches.

The model core (parameters, model, integrator, steady_state, measures,
simulation) is plain Python/numpy with no ROS imports; the nodes and the
command line are thin adapters around it.
"""
__version__ = "0.1.0"
