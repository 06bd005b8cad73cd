"""Tests of tak_thermo_ros/reports/."""
