import math


def reward_function(params):
    waypoints = params["waypoints"]
    n = len(waypoints)
    ahead = (params["closest_waypoints"][1] + 3) % n
    # i + 1 % n is i + (1 % n), i.e. i + 1: past the end when ahead is the last index.
    after = waypoints[ahead + 1 % n]
    before = waypoints[ahead]
    bend = math.degrees(math.atan2(after[1] - before[1], after[0] - before[0]))
    diff = abs((bend - params["heading"] + 180) % 360 - 180)
    return float(max(1e-3, 1 - diff / 180) * params["speed"])
