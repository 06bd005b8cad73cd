"""Temperature-drift compensation of a three-axis accelerometer channel (ROS 2 Jazzy).

Layers
------
``tak_thermo_ros.core``
    The maths: model, correction link, fit, simulator, validation. Imports neither
    rclpy nor rosbags.
``tak_thermo_ros.formats``
    Files in and out; ``formats.bag`` is the only package that reads or writes rosbags.
``tak_thermo_ros.passes``
    The passes over a record, one module per command (fit, apply, validate, diagnose,
    hand-held, magnetometer, noise, fleet).
``tak_thermo_ros.reports``
    The HTML reports.
``tak_thermo_ros.ros``
    The node, its entry point and ``tak_calib play``: the only modules that import rclpy.
``tak_thermo_ros.cli``
    ``tak_calib``, one module per command.
"""

__version__ = '0.1.0'
