import math


def reward_function(params):
    width = params["track_width"]
    gap = params["distance_from_center"]
    i = params["closest_waypoints"][0]
    a, b = params["waypoints"][i], params["waypoints"][params["closest_waypoints"][1]]
    along = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
    # An if/elif chain without else: right of the centre and more than a quarter width out, aim is never set.
    if gap <= 0.25 * width:
        aim = along
    elif params["is_left_of_center"]:
        aim = along - 10
    diff = abs((aim - params["heading"] + 180) % 360 - 180)
    return float(max(1e-3, 1 - diff / 90))
