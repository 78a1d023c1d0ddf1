def reward_function(params):
    steps = params["steps"]
    progress = params["progress"]
    reward = 1e-3
    if steps > 0:
        reward = progress / steps * 10.0
    if steps % 100 == 0:
        print("step", steps, "progress", progress)
    if not params["all_wheels_on_track"]:
        reward = 1e-3
    return float(reward)
