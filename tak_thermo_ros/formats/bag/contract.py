"""The bag contract: its topic names (:class:`Topics`), message types and the rosbags typestore.

The bag contract (each topic name is an option):

- ``/tak/counts``: ``geometry_msgs/msg/Vector3Stamped``, x, y, z = channel codes N.
- ``/tak/temp_code``: ``sensor_msgs/msg/Temperature``, ``temperature`` = raw code N_t.
- ``/tak/reference``: ``geometry_msgs/msg/Vector3Stamped``, true specific force (m/s^2),
  calibration runs only, published at least whenever it changes.
- ``/tak/imu/data_raw``: ``sensor_msgs/msg/Imu`` written by ``apply``.
- any other topic of a type in :data:`AUX_FIELDS` (a supply voltage, a pressure, a plain
  ``std_msgs`` number): an auxiliary signal ``aux:TOPIC`` (its obvious number) or
  ``aux:TOPIC:FIELD`` (another numeric field), read into the record's ``aux``. A stamped message
  is placed at its header stamp; a ``std_msgs`` number, which has no header, at its bag time.
"""

from __future__ import annotations

from dataclasses import dataclass

from rosbags.typesys import Stores, get_typestore

from tak_thermo_ros.core.effects import aux_signal

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
VECTOR3_STAMPED = 'geometry_msgs/msg/Vector3Stamped'
TEMPERATURE = 'sensor_msgs/msg/Temperature'
IMU = 'sensor_msgs/msg/Imu'
MAGNETIC_FIELD = 'sensor_msgs/msg/MagneticField'
NOMINAL_SCALE_KEY = 'tak_thermo_ros.nominal_scale'
"""Bag metadata ``custom_data`` key: nominal K0 per axis as ``'x,y,z'`` (counts per m/s^2)."""
AUX_FIELDS = aux_signal.AUX_FIELDS


@dataclass(frozen=True)
class Topics:
    """Topic names of the bag contract (counts input) and of a driver bag (Imu input)."""

    counts: str = '/tak/counts'
    temp_code: str = '/tak/temp_code'
    reference: str = '/tak/reference'
    imu: str = '/tak/imu/data_raw'
    raw_imu: str = '/imu/data_raw'
    temperature: str = '/imu/temperature'
    reference_rate: str = '/tak/reference_rate'
    compensated_imu: str = '/imu/data_compensated'
    mag: str = '/imu/mag'
    reference_field: str = '/tak/reference_field'
    compensated_mag: str = '/imu/mag_compensated'
    instance: int = 0
    """A flight log's sensor instance (PX4 ``multi_id``, ArduPilot ``I``); a bag has none."""
