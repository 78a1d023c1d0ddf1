# racer's reward function for following the centre line, written for racer with the rewards of the first example in
# AWS DeepRacer's developer guide ("follow the center line in time trials"), so that its rewards compare with
# DeepRacer's: 1.0 within 10 % of the track width of the centre line, 0.5 within 25 %, 0.1 within 50 % (on the
# road), 1e-3 beyond. A DeepRacer reward function: it runs unchanged in the DeepRacer console and DRfC.

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
