"""Tests of tak_thermo_ros/core/fit/."""
