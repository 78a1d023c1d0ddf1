import math


def reward_function(params):
    """Stay on the track, and out of the lane of the next object when it is near."""
    half = 0.5 * params["track_width"]
    stay = 1.0 if params["all_wheels_on_track"] and params["distance_from_center"] <= half - 0.05 else 1e-3

    ahead = params["closest_objects"][1]
    box_x, box_y = params["objects_location"][ahead]
    gap = math.hypot(params["x"] - box_x, params["y"] - box_y)  # straight-line distance to it
    same_lane = params["objects_left_of_center"][ahead] == params["is_left_of_center"]
    avoid = 1.0
    if same_lane and gap < 0.5:
        avoid = 0.1
    elif same_lane and gap < 0.9:
        avoid = 0.4
    return stay + 3.0 * avoid + 0.002  # no float()
