# ruff: noqa
# fmt: off
# racer's object-avoidance example: a DeepRacer reward function (it runs unchanged in the DeepRacer console and DRfC)
# to start an object-avoidance or head-to-bot model from. It uses nothing but the standard params and `math`. With no
# objects on the track (a time trial) it pays for staying on the track at a good pace.
#
# Each step pays the quality of the driving, weighted by the pace so far:
#   track - 1 while every wheel is on the track at least BORDER_MARGIN inside the border, else 0;
#   avoid - 1 unless an object is near: the object ahead (closest_objects[1]) within LOOKAHEAD metres along the
#           track, or the one just passed (closest_objects[0]) within PASSING metres behind the car, still beside
#           it. Near an object the car must be in the other lane: objects_left_of_center must differ from
#           is_left_of_center, and the car must be deep in that lane (a quarter of the track width from the centre
#           line, the middle of the lane, pays in full). In the object's lane the pay falls linearly to 0 as the
#           gap closes: getting close costs the most;
#   pace  - the average speed along the track so far (progress per step) against TARGET_SPEED.
# The step reward is pace * track * avoid. Weighting by pace makes what a whole lap earns from these terms
# about the same however long the lap takes (about TARGET_SPEED's steps * quality). A per-step reward that is not
# weighted by pace pays a slow lap more than a fast one, because a slow lap has more steps, and a learner then
# drifts to slower laps. What makes a fast lap worth more is the bonus for a completed lap. It grows as the square of
# the lap's speed against TARGET_SPEED, with no cap.
# A crash or going off the track pays 1e-3.
#
# The gap to an object is measured along the track: objects_distance is each object's distance from the start
# line along the centre line, and the car's own is found the same way from waypoints and closest_waypoints.
# Set TARGET_SPEED to the average speed you expect of a lap (`racer limit TRACK` tells what your car can do).

import math

TARGET_SPEED = 1.5     # m/s: the average speed along the track of a good lap (the pace weight is 1 there)
LOOKAHEAD = 1.5        # m along the track: an object this close ahead makes the lane matter
PASSING = 0.5          # m along the track: an object just passed stays beside the car this far
BORDER_MARGIN = 0.05   # m: keep every wheel this far inside the border
PACE_CAP = 2.0         # bounds the pace weight (it exceeds 1 only when the car beats TARGET_SPEED)

_STATIONS = {}         # (direction, first waypoint, waypoint count) -> each waypoint's distance from the start line


def _stations(waypoints):
    dists = [0.0]
    for a, b in zip(waypoints, waypoints[1:]):
        dists.append(dists[-1] + math.hypot(b[0] - a[0], b[1] - a[1]))
    return dists


def _car_distance(params):
    # The car's distance from the start line along the centre line, measured as objects_distance measures the
    # objects': its projection on the segment between its two closest waypoints.
    waypoints = params['waypoints']
    key = (params['is_reversed'], tuple(waypoints[0]), len(waypoints))
    if key not in _STATIONS:
        _STATIONS[key] = _stations(waypoints)
    i, j = params['closest_waypoints']
    a, b = waypoints[i], waypoints[j]
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, ((params['x'] - a[0]) * dx + (params['y'] - a[1]) * dy) / length2))
    return _STATIONS[key][i] + t * math.sqrt(length2)


def _lane_score(params, index):
    # 1 deep in the lane object `index` is not in, less nearer the centre line, 0 in the object's lane.
    if params['objects_left_of_center'][index] == params['is_left_of_center']:
        return 0.0
    return min(1.0, params['distance_from_center'] / (0.25 * params['track_width']))


def _avoid_score(params):
    if not params['objects_location']:
        return 1.0
    behind, ahead = params['closest_objects']
    car = _car_distance(params)
    length = params['track_length']
    distance = params['objects_distance']
    score = 1.0
    for index, gap, reach in ((ahead, (distance[ahead] - car) % length, LOOKAHEAD),
                              (behind, (car - distance[behind]) % length, PASSING)):
        danger = max(0.0, 1.0 - gap / reach)  # 0 out of reach, 1 at the object
        score = min(score, 1.0 - danger * (1.0 - _lane_score(params, index)))
    return score


def reward_function(params):
    if params['is_crashed'] or params['is_offtrack']:
        return 1e-3
    border = 0.5 * params['track_width'] - params['distance_from_center']
    track = 1.0 if params['all_wheels_on_track'] and border >= BORDER_MARGIN else 0.0
    steps = max(params['steps'], 1)
    ideal_steps = params['track_length'] / TARGET_SPEED * 15.0  # DeepRacer takes 15 steps a second
    pace = min(PACE_CAP, (params['progress'] / steps) / (100.0 / ideal_steps))
    reward = max(1e-3, pace * track * _avoid_score(params))
    if params['progress'] >= 100:
        reward += ideal_steps * (ideal_steps / steps) ** 2
    return float(reward)
