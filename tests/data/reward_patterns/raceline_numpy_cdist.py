import math as math

import numpy as np
from scipy.spatial import distance


def reward_function(params):
    x, y = params["x"], params["y"]

    # racer_loop's racing line, rebuilt as an array on every call: [x, y, speed m/s, seconds from the previous row].
    racing_line = np.array(
        [
            [4.0819, 1.2034, 4.0000, 0.1077],
            [4.5112, 1.2359, 4.0000, 0.1076],
            [4.9399, 1.2731, 4.0000, 0.1076],
            [5.3682, 1.3152, 4.0000, 0.1076],
            [5.7964, 1.3615, 4.0000, 0.1077],
            [6.2248, 1.4108, 3.9042, 0.1082],
            [6.6508, 1.4687, 3.3664, 0.1184],
            [7.0560, 1.5729, 2.7502, 0.1369],
            [7.4247, 1.7349, 2.0696, 0.1682],
            [7.7284, 1.9653, 1.5679, 0.2149],
            [7.9075, 2.2690, 1.5275, 0.2319],
            [7.8859, 2.6077, 1.6922, 0.2197],
            [7.6808, 2.9081, 2.3231, 0.1851],
            [7.3703, 3.1454, 3.0399, 0.1466],
            [7.0030, 3.3261, 3.7257, 0.1214],
            [6.6031, 3.4601, 4.0000, 0.1071],
            [6.1844, 3.5585, 4.0000, 0.1075],
            [5.7630, 3.6488, 4.0000, 0.1078],
            [5.3416, 3.7371, 4.0000, 0.1076],
            [4.9198, 3.8229, 4.0000, 0.1076],
            [4.4974, 3.9068, 4.0000, 0.1077],
            [4.0739, 3.9873, 3.8293, 0.1092],
            [3.6491, 4.0294, 3.6300, 0.1148],
            [3.2277, 4.0175, 3.4918, 0.1185],
            [2.8168, 3.9476, 3.3801, 0.1215],
            [2.4250, 3.8184, 3.2980, 0.1237],
            [2.0623, 3.6308, 3.2108, 0.1254],
            [1.7390, 3.3890, 2.9934, 0.1297],
            [1.4661, 3.0992, 2.5746, 0.1428],
            [1.2596, 2.7684, 2.1333, 0.1670],
            [1.1485, 2.4068, 1.9486, 0.1886],
            [1.1714, 2.0403, 1.9486, 0.1896],
            [1.3415, 1.7139, 2.1370, 0.1836],
            [1.6255, 1.4602, 2.5492, 0.1640],
            [1.9796, 1.2838, 2.9925, 0.1431],
            [2.3739, 1.1782, 3.3796, 0.1282],
            [2.7913, 1.1361, 3.7135, 0.1184],
            [3.2210, 1.1494, 4.0000, 0.1105],
            [3.6519, 1.1750, 4.0000, 0.1079],
        ]
    )

    def nearest_two(line):
        points = line[:, :2].copy()
        car = np.array([x, y]).reshape(1, -1)
        first = distance.cdist(car, points).argmin()
        points[first] = [999, 999]  # hide the nearest to find the second
        second = distance.cdist(car, points).argmin()
        return line[first], line[second]

    def off_line(a, b, car):
        # np.cross of 2-D vectors: deprecated by numpy 2.0, still what many reward functions do.
        return abs(np.cross(b - a, car - a) / np.linalg.norm(b - a))

    best, second = nearest_two(racing_line)
    gap = off_line(best[:2], second[:2], np.array([x, y]))
    reward = 1 + max(1e-3, 1 - gap)
    speed_gap = abs(best[2] - params["speed"])
    reward += 2 * (1 - speed_gap**2) ** 2 if speed_gap <= 1 else 0
    wanted = math.degrees(math.atan2(second[1] - best[1], second[0] - best[0]))
    if min(abs((wanted - params["heading"] + 180) % 360 - 180), abs((wanted - params["heading"]) % 360 - 180)) > 30:
        reward = 1e-3
    if params["progress"] == 100:
        reward += max(1e-3, 500 / 45 * (120 - params["steps"]))
    if params["is_offtrack"]:
        reward = 1e-3
    return float(reward)
