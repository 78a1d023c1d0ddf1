# racer's default reward function, used when the user gives none: the same function as follow_center_line.py
# (the rewards of AWS DeepRacer's first documented example), so the default behaves as DeepRacer's first example.
# A DeepRacer reward function: it runs unchanged in the DeepRacer console and DRfC.

BANDS = ((0.1, 1.0), (0.25, 0.5), (0.5, 0.1))  # (share of the track width from the centre line, reward)
OFF_ROAD = 1e-3


def reward_function(params):
    """The reward of the first band, counted out from the centre line, that holds the car."""
    distance = params["distance_from_center"]
    width = params["track_width"]
    for share, reward in BANDS:
        if distance <= share * width:
            return float(reward)
    return OFF_ROAD
