"""Files in and out, one module per format; the maths (:mod:`tak_thermo_ros.core`) reads none.

- :mod:`~tak_thermo_ros.formats.bag`: rosbag2 (mcap, sqlite3) through rosbags, whole or in blocks;
  the only package that imports rosbags;
- :mod:`~tak_thermo_ros.formats.cdr`: CDR messages read and written with numpy (the block decoder
  and encoder, the node's fixed-offset codec);
- :mod:`~tak_thermo_ros.formats.csv_log`: delimited logs (options, the text into columns, a record);
- :mod:`~tak_thermo_ros.formats.ulog`, :mod:`~tak_thermo_ros.formats.dataflash`: PX4 ULogs and ArduPilot
  DataFlash logs (one :class:`~tak_thermo_ros.formats.flight_log.FlightLog`);
- :mod:`~tak_thermo_ros.formats.px4_params`, :mod:`~tak_thermo_ros.formats.ardupilot_params`: the
  firmwares' temperature parameters (:mod:`~tak_thermo_ros.formats.firmware`: what they carry);
- :mod:`~tak_thermo_ros.formats.records`: every record read the same way (the passes' one door);
- :mod:`~tak_thermo_ros.formats.calibration_file`: the calibration file (the node's parameters YAML)
  and its one parser;
- :mod:`~tak_thermo_ros.formats.kalibr`: Kalibr-style imu.yaml noise files;
- :mod:`~tak_thermo_ros.formats.scenario`: the simulator's scenario file;
- :mod:`~tak_thermo_ros.formats.files`: atomic outputs and the one overwrite rule.

Nothing is imported here: the node loads the calibration file's parser without rosbags.
"""
