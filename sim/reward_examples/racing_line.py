# ruff: noqa
# fmt: off
# racer's racing example: a DeepRacer reward function (it runs unchanged in the DeepRacer console and DRfC) that
# pays for driving a racing line at a racing speed. It uses nothing but the standard params and `math`.
#
# On its first call on a track (and direction) it builds the line from params['waypoints'] and
# params['track_width']: the centre line relaxed towards the midpoint of its neighbours, point by point (which
# lowers its curvature: it cuts to the inside of each bend), kept inside the track less a margin. That is the
# line `racer limit` optimises more exactly. Each point gets a target speed: the highest at which the car holds
# the line's curvature (LATERAL_ACCEL), lowered before bends by a braking pass (BRAKE). Set the three
# constants to your car: `racer limit TRACK --json F` prints its measured limits (car_limits).
#
# Each step pays the quality of the driving, weighted by the pace so far:
#   line  - how close the car is to the line (0 at half a track width away);
#   speed - how close the action's speed is to the line's target speed there;
#   pace  - progress per step so far against the pace of the line driven at its target speeds.
# The step reward is pace * (line + speed) / 2. Weighting by pace makes what a whole lap earns from these terms
# about the same however long the lap takes (about ideal steps * quality): a per-step reward that is not weighted
# so pays a slow lap more than a fast one, because a slow lap has more steps, and a learner then drifts to slower
# laps. What makes a fast lap worth more is the bonus for a completed lap, which grows as the square of the lap's
# speed (ideal steps / steps) with no cap, so a lap faster than this line's estimate still pays more.
# Off the track it pays 1e-3.
#
# LAP_BONUS sets how much risk that trade takes. A lap that ends off the track loses its bonus and the rest of its
# step rewards, so the learner weighs a faster lap's larger bonus against more laps lost: with the bonus growing
# as the square of the pace alone (LAP_BONUS = 0), a lap 10 % faster than 1.3 x the line's steps pays as much as
# 10 % of laps lost at a random point. LAP_BONUS adds that many of the line's ideal steps to every completed lap's
# bonus whatever its pace, so a lost lap costs more and the same pace is worth no more: at 1.0 the same 10 % of
# pace is worth 5.5 % of laps, at 2.0 3.8 %. It ships at 0: raised to 1.0 for DeepRacer's Gazebo car, racer's
# benchmark measured slower laps and no fewer lost ones (racer's docs/racing.md).

import math

MAX_SPEED = 4.0        # m/s: the fastest speed of your action space
LATERAL_ACCEL = 5.0    # m/s²: the sideways acceleration your car holds in a bend
BRAKE = 5.0            # m/s²: how hard it brakes
MARGIN = 0.1           # m: the line keeps its centre this far inside each border
ITERATIONS = 300       # relaxation sweeps building the line
PACE_CAP = 2.0         # bounds the pace weight (it exceeds 1 only when the car beats this line's estimate)
LAP_BONUS = 0.0        # a completed lap's bonus whatever its pace, in the line's ideal steps (see above)

_LINES = {}            # (direction, first waypoint, waypoint count) -> (points, target speeds, ideal steps a lap)


def _distance(a, b):
    return math.hypot(a[0] - b[0], a[1] - b[1])


def _build(waypoints, track_width):
    centre = [(float(p[0]), float(p[1])) for p in waypoints]
    if len(centre) > 2 and _distance(centre[0], centre[-1]) < 1e-3:
        centre = centre[:-1]  # a loop repeats its first waypoint at the end
    n = len(centre)
    normals = []
    for i in range(n):
        a, b = centre[i - 1], centre[(i + 1) % n]
        dx, dy = b[0] - a[0], b[1] - a[1]
        norm = math.hypot(dx, dy) or 1.0
        normals.append((-dy / norm, dx / norm))
    room = max(track_width / 2 - MARGIN, 0.0)
    offsets = [0.0] * n
    for _ in range(ITERATIONS):
        for i in range(n):
            p = [centre[i][0] + offsets[i] * normals[i][0], centre[i][1] + offsets[i] * normals[i][1]]
            j, k = (i - 1) % n, (i + 1) % n
            prev = (centre[j][0] + offsets[j] * normals[j][0], centre[j][1] + offsets[j] * normals[j][1])
            nxt = (centre[k][0] + offsets[k] * normals[k][0], centre[k][1] + offsets[k] * normals[k][1])
            mid = ((prev[0] + nxt[0]) / 2, (prev[1] + nxt[1]) / 2)
            # Move halfway to the midpoint, sideways only, and stay inside the track.
            step = (mid[0] - p[0]) * normals[i][0] + (mid[1] - p[1]) * normals[i][1]
            offsets[i] = max(-room, min(room, offsets[i] + 0.5 * step))
    line = [(centre[i][0] + offsets[i] * normals[i][0], centre[i][1] + offsets[i] * normals[i][1]) for i in range(n)]
    speeds = []
    for i in range(n):
        a, b, c = line[i - 1], line[i], line[(i + 1) % n]
        cross = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0])
        denom = _distance(a, b) * _distance(b, c) * _distance(a, c)
        curvature = 2 * abs(cross) / denom if denom > 0 else 0.0
        speeds.append(min(MAX_SPEED, math.sqrt(LATERAL_ACCEL / curvature)) if curvature > 0 else MAX_SPEED)
    for _ in range(2):  # braking pass, twice round the loop so that the first bend is braked for too
        for i in range(n - 1, -1, -1):
            k = (i + 1) % n
            speeds[i] = min(speeds[i], math.sqrt(speeds[k] ** 2 + 2 * BRAKE * _distance(line[i], line[k])))
    lap_time = sum(2 * _distance(line[i], line[(i + 1) % n]) / (speeds[i] + speeds[(i + 1) % n]) for i in range(n))
    return line, speeds, lap_time * 15.0  # DeepRacer takes 15 steps a second


def _nearest(line, point, hint):
    n = len(line)
    best, best_d = hint % n, float("inf")
    for i in range(hint - 4, hint + 5):
        d = _distance(line[i % n], point)
        if d < best_d:
            best, best_d = i % n, d
    return best


def _distance_to_segment(a, b, p):
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / length2))
    return math.hypot(p[0] - a[0] - t * dx, p[1] - a[1] - t * dy)


def reward_function(params):
    if params['is_offtrack'] or params['is_crashed']:
        return 1e-3
    waypoints = params['waypoints']
    key = (params['is_reversed'], tuple(waypoints[0]), len(waypoints))
    if key not in _LINES:
        _LINES[key] = _build(waypoints, params['track_width'])
    line, speeds, ideal_steps = _LINES[key]
    car = (params['x'], params['y'])
    i = _nearest(line, car, params['closest_waypoints'][1])
    n = len(line)
    gap = min(_distance_to_segment(line[i - 1], line[i], car), _distance_to_segment(line[i], line[(i + 1) % n], car))
    line_score = max(0.0, 1.0 - gap / (0.5 * params['track_width']))
    target = speeds[i]
    speed_score = max(0.0, 1.0 - abs(params['speed'] - target) / MAX_SPEED)
    steps = max(params['steps'], 1)
    pace = min(PACE_CAP, (params['progress'] / steps) / (100.0 / ideal_steps))
    reward = max(1e-3, pace * (line_score + speed_score) / 2.0)
    if params['progress'] >= 100:
        reward += ideal_steps * (LAP_BONUS + (ideal_steps / steps) ** 2)
    return float(reward)
