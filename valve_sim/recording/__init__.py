"""Bag I/O: MCAP as rosbag2 writes it, the tick messages as CDR bytes, replay.

Lives here: the MCAP writer and reader, the CDR message layout, valve_node's topic
layout, a replay publisher.
May import: valve_sim.core, valve_sim.analysis, message packages. rclpy only inside
functions that need a live context (replay), never at import time.
"""
