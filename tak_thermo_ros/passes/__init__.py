"""The passes over a record, one module per command: open once, survey, blocks, core.

:mod:`.run` opens and surveys a record and runs sensor passes over its blocks; :mod:`.fit`,
:mod:`.apply`, :mod:`.validate`, :mod:`.diagnose` are the commands' passes over the IMU;
:mod:`.handheld` a record turned by hand; :mod:`.magnetometer` the magnetometer; :mod:`.noise`
the noise model's sources; :mod:`.fleet` a batch of units on Dask. Nothing is imported here.
"""
