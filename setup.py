"""ament_python package valve_sim: builds with colcon on ROS 2 Jazzy and installs with pip.

On a ROS install, rclpy and the message packages come from ROS (package.xml). In a
plain virtual environment `pip install -e .[wheels,test]` brings them from PyPI.
"""

from glob import glob

from setuptools import find_packages, setup


PACKAGE = 'valve_sim'
PYPI_DEPENDENCIES = [
    'numpy',
    'scipy',
    'matplotlib',
    'pyyaml',
    'numba',
    'mcap',
    'mcap-ros2-support',
]
ROS_WHEELS = ['ros-jazzy-rclpy', 'ros-jazzy-common-interfaces', 'ros-jazzy-rmw-fastrtps-cpp']

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
    ],
    install_requires=['setuptools'],
    extras_require={
        'wheels': PYPI_DEPENDENCIES + ROS_WHEELS,
        'test': ['pytest', 'pytest-timeout', 'psutil', 'rosbags'],
    },
    zip_safe=True,
    maintainer='valve_sim developers',
    maintainer_email='dev@valve-sim.local',
    description='Virtual direct-pressure-sensing water-hydraulic relief valve for ROS 2 test benches',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'valve-sim = valve_sim.commands.cli:main',
            'valve_node = valve_sim.ros.valve_node:main',
            'analyser_node = valve_sim.ros.analyser_node:main',
        ],
    },
)
