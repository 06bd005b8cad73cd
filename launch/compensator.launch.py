"""Launch the ``compensator`` node with a parameters file.

::

    ros2 launch tak_thermo_ros compensator.launch.py params_file:=tak_params.yaml namespace:=imu0

``params_file`` defaults to the installed example ``config/compensator.yaml`` (an example
calibration: use the file ``tak_calib fit`` wrote for your unit).
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    """The compensator node, its parameters file and namespace as launch arguments."""
    default_params = os.path.join(get_package_share_directory('tak_thermo_ros'), 'config', 'compensator.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='calibration and node parameters (the file tak_calib fit writes)'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of the node and of its relative topics'),
        Node(
            package='tak_thermo_ros',
            executable='compensator',
            name='compensator',
            namespace=LaunchConfiguration('namespace'),
            parameters=[LaunchConfiguration('params_file')],
            output='screen',
            emulate_tty=True,
        ),
    ])
