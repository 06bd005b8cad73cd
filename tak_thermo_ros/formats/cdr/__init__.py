"""CDR-serialised ROS 2 messages read and written with numpy and struct (no rosbags): one module per use.

- :mod:`~tak_thermo_ros.formats.cdr.schema`: the message types' fields in CDR order, one
  message's layout checked as rosbags checks it, the plain-Python reference decoder;
- :mod:`~tak_thermo_ros.formats.cdr.decoder`: a chunk of messages decoded at once into arrays
  (:func:`~tak_thermo_ros.formats.cdr.decoder.decode_messages`, what the bag readers use);
- :mod:`~tak_thermo_ros.formats.cdr.encoder`: a block of messages serialised at once (what the
  bag writers use);
- :mod:`~tak_thermo_ros.formats.cdr.fixed`: one message at a time at fixed offsets (the
  ``compensator`` node's raw path).

Nothing is imported here: the node loads the fixed-offset codec without the block decoder.
"""
