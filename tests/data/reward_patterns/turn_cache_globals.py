import math

import numpy as np

turn_points = None
turn_sides = None


def angle_change(a, b, c):
    first = np.arctan2(b[1] - a[1], b[0] - a[0])
    second = np.arctan2(c[1] - b[1], c[0] - b[0])
    return (np.degrees(second - first) + 180) % 360 - 180


def find_turn_points(waypoints):
    found = []
    for i in range(1, len(waypoints) - 1):
        if abs(angle_change(waypoints[i - 1], waypoints[i], waypoints[i + 1])) >= 4:
            found.append(i)
    return found


def sides_of(points, waypoints):
    sides = {"left": [], "right": []}
    for i in points:
        change = angle_change(waypoints[i - 1], waypoints[i], waypoints[i + 1])
        sides["left" if change > 0 else "right"].append(i)
    return sides


def shifted(x, y, angle, distance):
    # float() of a one-element array: numpy 1.24 (DeepRacer's) takes it, numpy >= 2.4 refuses it.
    return float(x + np.cos([np.radians(angle)]) * distance), float(y + np.sin([np.radians(angle)]) * distance)


def reward_function(params):
    global turn_points, turn_sides
    waypoints = params["waypoints"]
    if turn_points == None:  # noqa: E711 - as users write it
        turn_points = find_turn_points(waypoints)
    if turn_sides == None:  # noqa: E711
        turn_sides = sides_of(turn_points, waypoints)

    prev_i, next_i = params["closest_waypoints"]
    a, b = waypoints[prev_i], waypoints[next_i]
    track_heading = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
    upcoming = [i for i in turn_points if i >= next_i][:1]
    if upcoming and upcoming[0] in turn_sides["left"]:
        target = shifted(a[0], a[1], track_heading + 90, params["track_width"] / 4)
    elif upcoming:
        target = shifted(a[0], a[1], track_heading - 90, params["track_width"] / 4)
    else:
        target = (a[0], a[1])
    gap = math.hypot(params["x"] - target[0], params["y"] - target[1])
    reward = 1.0 if gap <= params["track_width"] / 2 else 1e-3
    if next_i not in turn_points:
        reward *= params["speed"]
    if params["is_offtrack"]:
        reward = 1e-3
    print(params)
    print("reward: ", reward)
    return float(reward)
