r"""Launch the ``compensator`` node between an IMU driver and a state estimator.

::

    ros2 launch tak_thermo_ros compensator.launch.py params_file:=tak_params.yaml \
        driver_imu_topic:=/driver/imu/data_raw driver_temperature_topic:=/driver/imu/temperature \
        estimator_imu_topic:=/ekf/imu

Two IMUs, two compensators, each with its unit's file (``tak_calib fit`` writes the node key
``/**/compensator``, which matches the node in any namespace)::

    ros2 launch tak_thermo_ros compensator.launch.py namespace:=imu0 params_file:=imu0.yaml \
        driver_imu_topic:=/imu0/data_raw driver_temperature_topic:=/imu0/temperature \
        estimator_imu_topic:=/imu0/data_compensated

The pipeline, with a driver calibration (file version 2, ``input: imu``)::

    IMU driver                compensator                              estimator
    Imu         --> driver_imu_topic         --> imu/data_raw
    Temperature --> driver_temperature_topic --> imu/temperature
                                                 imu/data_compensated --> estimator_imu_topic --> Imu

The node's relative topics are remapped onto the driver's and the estimator's names, so neither
needs changing. The three topic arguments default to the node's own relative names, which
resolve in ``namespace`` (``namespace:=imu0``: ``/imu0/imu/data_raw`` and so on); give absolute
names (``/driver/imu/data_raw``) to leave the namespace. Start the driver and the estimator as
usual (their own launch files); with ``start_estimator:=true`` this file also starts
``robot_localization``'s ``ekf_node`` with ``estimator_params_file`` (it must read
``imu0: <estimator_imu_topic>``).

With a magnetometer in the calibration (``mag``), ``imu/mag`` and ``imu/mag_compensated`` are
remapped from ``driver_mag_topic`` and ``estimator_mag_topic``.

With a counts calibration (version 1, the paper's codes) the node's topics are ``tak/counts``,
``tak/temp_code`` and ``tak/imu/data_raw``; they are remapped from the same three arguments.

``params_file`` defaults to the installed example ``config/compensator_driver.yaml`` (an example
calibration: use the file ``tak_calib fit`` wrote for your unit).
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

DRIVER_TOPICS = ('imu/data_raw', 'imu/temperature', 'imu/data_compensated')
COUNTS_TOPICS = ('tak/counts', 'tak/temp_code', 'tak/imu/data_raw')
MAG_TOPICS = ('imu/mag', 'imu/mag_compensated')


def generate_launch_description() -> LaunchDescription:
    """The compensator with its parameters, namespace and the driver/estimator topic remapping."""
    share = get_package_share_directory('tak_thermo_ros')
    default_params = os.path.join(share, 'config', 'compensator_driver.yaml')
    driver_imu = LaunchConfiguration('driver_imu_topic')
    driver_temperature = LaunchConfiguration('driver_temperature_topic')
    estimator_imu = LaunchConfiguration('estimator_imu_topic')
    remappings = []
    for raw, temperature, corrected in (DRIVER_TOPICS, COUNTS_TOPICS):
        remappings += [(raw, driver_imu), (temperature, driver_temperature), (corrected, estimator_imu)]
    remappings += [(MAG_TOPICS[0], LaunchConfiguration('driver_mag_topic')),
                   (MAG_TOPICS[1], LaunchConfiguration('estimator_mag_topic'))]
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='calibration and node parameters (the file tak_calib fit writes)'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of the compensator node (relative topic names follow it)'),
        DeclareLaunchArgument('driver_imu_topic', default_value='imu/data_raw',
                              description="the driver's Imu (or counts) topic (relative: in namespace)"),
        DeclareLaunchArgument('driver_temperature_topic', default_value='imu/temperature',
                              description="the driver's sensor_msgs/msg/Temperature topic"),
        DeclareLaunchArgument('estimator_imu_topic', default_value='imu/data_compensated',
                              description='the topic the estimator reads the corrected Imu from'),
        DeclareLaunchArgument('driver_mag_topic', default_value='/imu/mag',
                              description="the driver's sensor_msgs/msg/MagneticField topic (tesla)"),
        DeclareLaunchArgument('estimator_mag_topic', default_value='/imu/mag_compensated',
                              description='the topic the estimator reads the corrected MagneticField from'),
        DeclareLaunchArgument('start_estimator', default_value='false',
                              description="also start robot_localization's ekf_node"),
        DeclareLaunchArgument('estimator_params_file', default_value='',
                              description='ekf_node parameters (imu0: <estimator_imu_topic>)'),
        Node(
            package='tak_thermo_ros',
            executable='compensator',
            name='compensator',
            namespace=LaunchConfiguration('namespace'),
            parameters=[LaunchConfiguration('params_file')],
            remappings=remappings,
            output='screen',
            emulate_tty=True,
        ),
        Node(
            package='robot_localization',
            executable='ekf_node',
            name='ekf_filter_node',
            parameters=[LaunchConfiguration('estimator_params_file')],
            condition=IfCondition(LaunchConfiguration('start_estimator')),
            output='screen',
        ),
    ])
