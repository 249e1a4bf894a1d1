"""Test isolation (../shared/spec/platform.md): every test session picks its own
ROS_DOMAIN_ID and keeps discovery on localhost, before anything imports rclpy,
so parallel or leftover runs never cross-talk. Child processes inherit both."""
import os
import random

os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 101))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("MPLBACKEND", "Agg")
