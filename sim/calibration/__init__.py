"""Sim2real calibration: the car against trajectories measured in DeepRacer's simulator or on a real car.

- ``sim.calibration.logs`` reads the measured logs into one normalized form, :class:`Trajectory`;
- ``sim.calibration.replay`` replays their commands on the simulator's MuJoCo car over 1 s windows;
- ``sim.calibration.fit`` chooses the effects the car lacks, fits them and scores them on held-out episodes;
- ``sim.calibration.presets`` remakes the car presets' fit from DeepRacer's public logs, which the user supplies.

The effects themselves live in ``common.car_calibration`` (the file) and ``sim.actuation`` (the maths).
"""

from sim.calibration.logs import MIN_ROWS, LogError, Trajectory, read_log, read_logs

__all__ = ["MIN_ROWS", "LogError", "Trajectory", "read_log", "read_logs"]
