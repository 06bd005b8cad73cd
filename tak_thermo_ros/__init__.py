"""Temperature-drift compensation of a three-axis accelerometer channel (ROS 2 Jazzy).

Layers
------
``tak_thermo_ros.core``
    The maths: model, correction link, fit, simulator, validation. Imports neither
    rclpy nor rosbags.
``tak_thermo_ros.formats.bag``
    The only module that reads or writes rosbags.
``tak_thermo_ros.node``
    The only module that imports rclpy.
"""

__version__ = '0.1.0'
