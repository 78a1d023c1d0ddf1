import math


def reward_function(params):
    reward = 1e-3
    if params["all_wheels_on_track"]:
        reward = 1.0 if not params["is_left_of_center"] else 0.5  # keep to the right-hand lane
    reward += params["progress"] * 0.5 / 100

    ahead = params["closest_objects"][1]
    # objects_distance is the object's distance along the centre line from the START LINE, not from the car:
    # read as "the distance to the object", this fires only for an object near the start line.
    if params["objects_distance"][ahead] < 0.8:
        reward *= 0.5
    # A list is truthy whenever it holds anything: with objects on the track this branch never runs.
    if not params["objects_left_of_center"]:
        reward += 1.0
    gap = math.dist(params["objects_location"][ahead], (params["x"], params["y"]))
    if gap < 0.5:
        reward *= 0.2
    if params["progress"] == 100:
        reward += 200
    return reward  # no float()
