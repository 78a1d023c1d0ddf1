# Two definitions of reward_function in one file: Python keeps the last one, and so does DeepRacer.
# The first one fails on slow steps (reward is never set when speed <= 2).


def reward_function(params):
    speed = params["speed"]
    if speed > 2.0:
        reward = speed
    else:
        speed * 0.5  # noqa: B018 - meant to be "reward = speed * 0.5"
    if abs(params["steering_angle"]) > 15:
        reward *= 0.9
    return float(reward)


def reward_function(params):  # noqa: F811 - the one that counts
    speed = params["speed"]
    reward = 1e-3
    if params["all_wheels_on_track"]:
        reward = speed + (1 - params["distance_from_center"] / (params["track_width"] / 2)) * 0.1
        reward += params["progress"] / 100
    return float(reward)
