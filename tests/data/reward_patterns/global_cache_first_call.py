import math

TRACK = None  # filled on the first call, from that call's waypoints


def reward_function(params):
    global TRACK
    if TRACK is None:
        TRACK = [tuple(p) for p in params["waypoints"]]
    # IndexError if TRACK holds another track's (fewer) waypoints.
    x0, y0 = TRACK[params["closest_waypoints"][0]]
    x1, y1 = TRACK[params["closest_waypoints"][1]]
    assert len(TRACK) == len(params["waypoints"]), "cached a different track"
    return 1.0 / (1.0 + math.hypot(params["x"] - (x0 + x1) / 2, params["y"] - (y0 + y1) / 2))
