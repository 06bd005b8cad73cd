"""Import a delimited (CSV/TSV) log into the bag contract: a static thermal run, or a driver's log.

Most users calibrate the way PX4 and ArduPilot do: the board lies still in one orientation and
the temperature is swept; the log comes as a delimited text file with a time column, three
acceleration columns and a temperature column. This package turns such a log into a
:class:`~tak_thermo_ros.core.records.record.ChannelRecord` (pure: no rosbags; ``bagio.write_record``
writes it):

- :mod:`~tak_thermo_ros.formats.csv_log.options`: how to read a log
  (:class:`~tak_thermo_ros.formats.csv_log.options.CsvImportOptions`, the units) and what the import gives
  (:class:`~tak_thermo_ros.formats.csv_log.options.ImportedLog`);
- :mod:`~tak_thermo_ros.formats.csv_log.table`: the file's text into columns (the header, the
  time column in nanoseconds, numbers);
- :mod:`~tak_thermo_ros.formats.csv_log.reader`: the columns into a record, checked
  (:func:`~tak_thermo_ros.formats.csv_log.reader.read_csv_log`,
  :func:`~tak_thermo_ros.formats.csv_log.reader.parse_csv_log`).

Nothing is imported here: import from the module that holds a name.

Units and rounding
------------------
- Time: the ``time_unit`` column (``s``, ``ms``, ``us``, ``ns``) becomes int64 nanoseconds.
  Integer text is converted exactly; decimal text through :class:`decimal.Decimal`, rounded
  to the nearest nanosecond. Stamps must strictly increase and fit the bag's time type
  (``builtin_interfaces/Time``: whole seconds 0 .. 2**31 - 1, i.e. 1970-01-01 .. 2038-01-19);
  a stamp outside it is an error naming the line and the column, as is a step of a year or more
  between rows (a clock step, :func:`~tak_thermo_ros.core.records.plausible.clock_step`).
- Numbers: ASCII decimal text only (:data:`ASCII_NUMBER`); a wanted column named twice in the
  header is refused.
- Acceleration: the columns in ``m/s^2`` or ``g`` (``1 g = 9.80665 m/s^2``, the standard
  value, whatever the local gravity) become channel codes
  ``N = round(a / acc_resolution)`` with ``acc_resolution`` in m/s^2 per count (round half to
  even). The nominal scale written to the bag is ``1 / acc_resolution`` counts per m/s^2 on each
  axis; ``fit`` holds an axis's scale at that value when the axis sees one input only.
  Every code must stay strictly inside the 16-bit range (``-32768 < N < 32767``; the rails
  count as saturated): a value beyond it is an error naming the column and the row.
- Temperature: the column in degrees Celsius (mostly kelvin-like or implausible values are refused,
  :func:`~tak_thermo_ros.core.records.plausible.temperature_unit_problem`) becomes the sensor code
  ``N_t = round(T / temp_resolution)``, ``temp_resolution`` in degrees per code.
- A driver's log (gyroscope columns): the values as logged, in SI units; the temperature column
  is optional (a driver that logs none: no temperature topic) and may be constant (a noise run);
  magnetometer columns (``mag_columns``, in ``mag_unit``) become ``/imu/mag`` in tesla (at
  their own stamps where their cells are empty in other rows). No reference is written unless
  given, and the board may move (a unit turned by hand): ``fit`` decides what the record
  determines.
- Reference (the true specific force, m/s^2, sensor frame): the run is static, so it is one
  constant vector, written once at the first stamp. Unless given explicitly, it is estimated
  as the mean measured direction scaled to local gravity,
  ``g_local * mean(a) / |mean(a)|``: this takes the tilt from the data and attributes the
  error of the mean magnitude to the channel. A component of the mean offset perpendicular to
  gravity is indistinguishable from tilt on a single orientation and ends in the reference.
"""
