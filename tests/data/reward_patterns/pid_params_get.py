import math

import numpy as np


class Pid:
    def __init__(self, kp, ki, kd):
        self.kp, self.ki, self.kd = kp, ki, kd
        self.integral = 0.0
        self.last_error = 0.0
        self.calls = 0

    def update(self, error):
        self.calls += 1
        self.integral += error
        derivative = error - self.last_error
        self.last_error = error
        return self.kp * error + self.ki * self.integral + self.kd * derivative


class SpeedScaledPid(Pid):
    def update(self, error, speed=0.0):
        return (1.0 + speed / 4.0) * super().update(error)


# One controller for the whole run: its integral carries over from call to call and episode to episode.
controller = SpeedScaledPid(kp=0.8, ki=0.01, kd=0.2)


def bend_at(waypoints, closest):
    a = np.array(waypoints[closest[0]])
    b = np.array(waypoints[closest[1]])
    c = np.array(waypoints[(closest[1] + 1) % len(waypoints)])
    first = np.arctan2(b[1] - a[1], b[0] - a[0])
    second = np.arctan2(c[1] - b[1], c[0] - b[0])
    return np.abs((second - first + np.pi) % (2 * np.pi) - np.pi)


def reward_function(params):
    # Keys DeepRacer never sends, read with defaults: the dict must behave as a plain dict.
    last_speed = params.get("previous_speed", params["speed"])
    history = params.get("steering_history", [params["steering_angle"]])
    if params.get("is_offtrack") or not params.get("all_wheels_on_track", True):
        return 1e-3

    bend = bend_at(params["waypoints"], params["closest_waypoints"])
    target_speed = 4.0 if bend < 0.05 else max(1.0, 3.0 - 10.0 * bend)
    correction = controller.update(params["distance_from_center"] / params["track_width"], params["speed"])

    reward = 1.0
    reward += 2.0 * math.exp(-abs(params["speed"] - target_speed))
    reward += 1.0 if abs(correction) < 0.2 else 0.0
    if len(history) > 1 and np.any(np.abs(np.diff(history)) > 10):
        reward *= 0.5
    if params["speed"] > last_speed:
        reward += 0.2
    return float(reward)
