def reward_function(params):
    """The speed, returned as params holds it (no float())."""
    if not params["all_wheels_on_track"]:
        return 1e-3
    return params["speed"]
