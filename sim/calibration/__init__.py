"""Sim2real calibration: the car against trajectories measured in DeepRacer's simulator or on a real car.

``sim.calibration.logs`` reads the measured logs into one normalized form, :class:`Trajectory`.
"""

from sim.calibration.logs import MIN_ROWS, LogError, Trajectory, read_log, read_logs

__all__ = ["MIN_ROWS", "LogError", "Trajectory", "read_log", "read_logs"]
