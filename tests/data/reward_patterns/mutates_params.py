SEEN = []


def reward_function(params):
    SEEN.append(len(params["waypoints"]))
    assert SEEN[0] == SEEN[-1], "an earlier call's change to params reached this one"
    params["waypoints"].append((0.0, 0.0))
    params["waypoints"].reverse()
    params["closest_waypoints"][0] = -1
    return 1.0
