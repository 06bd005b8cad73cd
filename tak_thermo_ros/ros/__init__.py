"""The ROS side: the ``compensator`` node (:mod:`.node`), its entry point (:mod:`.main`), ``tak_calib play``.

The only modules that import rclpy (:mod:`.main` also holds the executor; :mod:`.player` is ``play``;
:mod:`.parameters`, the node's own parameters, imports none). Nothing is imported here: the node's
import path stays its own.
"""
