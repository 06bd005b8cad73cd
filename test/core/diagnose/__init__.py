"""Tests of tak_thermo_ros/core/diagnose/."""
