import math

import numpy as np
from scipy import signal


class Smoothed:
    """The racing line: the centre line smoothed on the first call, kept in class attributes for every later call."""

    POINTS = []
    SPEEDS = []
    builds = 0

    @classmethod
    def get(cls, waypoints):
        if not cls.POINTS:
            print("smoothing the centre line")
            cls.POINTS = cls.smooth([list(p) for p in waypoints])
            cls.builds += 1
        return cls.POINTS

    @staticmethod
    def smooth(centre, passes=120, weights=(0.1, 0.15, 0.5, 0.15, 0.1), max_offset=0.25):
        n = len(centre)
        line = [list(p) for p in centre]
        for _ in range(passes):
            new = []
            for i in range(n):
                x = sum(w * line[(i + k - 2) % n][0] for k, w in enumerate(weights))
                y = sum(w * line[(i + k - 2) % n][1] for k, w in enumerate(weights))
                while math.hypot(x - centre[i][0], y - centre[i][1]) > max_offset:
                    x = 0.95 * x + 0.05 * centre[i][0]
                    y = 0.95 * y + 0.05 * centre[i][1]
                new.append([x, y])
            line = new
        return line

    @classmethod
    def speeds(cls, line, low=1.0, high=4.0):
        if cls.SPEEDS:
            return cls.SPEEDS
        n = len(line)
        radii = []
        for i in range(n):
            a, b, c = line[i - 1], line[i], line[(i + 1) % n]
            area = abs((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])) / 2
            sides = math.dist(a, b) * math.dist(b, c) * math.dist(c, a)
            radii.append(999.0 if area < 1e-9 else sides / (4 * area))
        scale = low / min(radii) ** 0.5
        cls.SPEEDS = [min(high, scale * r**0.5) for r in radii]
        return cls.SPEEDS


UPSAMPLE = False


def resampled(points, factor):
    return [list(p) for p in signal.resample(np.array(points), len(points) * factor)]


def reward_function(params):
    print("params:", {key: value for key, value in params.items() if key != "waypoints"})
    line = Smoothed.get(params["waypoints"])
    if UPSAMPLE:
        line = resampled(line, 2)
    speeds = Smoothed.speeds(line)
    here = (params["x"], params["y"])
    nearest = min(line, key=lambda p: math.dist(p, here))
    target = speeds[line.index(nearest)]  # list.index of a [x, y] list: compares lists of floats

    if params["is_offtrack"] or params["is_crashed"]:
        return -5.0 if target <= 2.5 else -2.0
    distance = math.dist(nearest, here)
    on_line = max(1e-3, 0.5 - distance / params["track_width"])
    pace = max(1e-3, 0.5 - abs(params["speed"] - target) / 3.0) * 2
    return on_line + pace
