"""Tests of tak_thermo_ros/core/simulation/."""
