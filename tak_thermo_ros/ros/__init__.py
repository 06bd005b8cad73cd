"""The ROS side: the ``compensator`` node (:mod:`.node`), its entry point (:mod:`.main`), ``tak_calib play``.

The only modules that import rclpy (:mod:`.player` is ``play``). Nothing is imported here: the node's
import path stays its own.
"""
