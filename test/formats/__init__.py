"""Tests of tak_thermo_ros/formats/."""
