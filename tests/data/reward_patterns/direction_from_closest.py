import math


def reward_function(params):
    waypoints = params["waypoints"]
    prev_point = waypoints[params["closest_waypoints"][0]]
    next_point = waypoints[params["closest_waypoints"][1]]
    track_direction = math.degrees(math.atan2(next_point[1] - prev_point[1], next_point[0] - prev_point[0]))
    direction_diff = abs(track_direction - params["heading"])
    if direction_diff > 180:
        direction_diff = 360 - direction_diff
    reward = 1.0
    if direction_diff > 10.0:
        reward *= 0.5
    return float(reward)
