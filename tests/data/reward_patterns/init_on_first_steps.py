STATE = {}


def reward_function(params):
    if params["steps"] == 2:  # the simapp's first rewarded step: step 1 is the prepare step
        STATE["start"] = params["closest_waypoints"][0]
        STATE["width"] = params["track_width"]
    if params["steps"] <= 2:
        assert "start" in STATE
    # KeyError if the first call of an episode never came with steps == 2.
    return 1.0 if params["distance_from_center"] < STATE["width"] / 4 else 0.1
