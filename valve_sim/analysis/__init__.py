"""Response analysis on arrays: the six step-response measures, signals, plots.

Lives here: the measures and step detection, streaming step analysis, signal
mapping and joining, the paper's reference data, matplotlib figures.
May import: valve_sim.core. No ROS and no bag files: commands read bags and hand
arrays to this wing.
"""
