# racer's reward function for staying between the borders, written for racer with the rewards of the second example
# in AWS DeepRacer's developer guide ("stay inside the two borders in time trials"): 1.0 while all wheels are on
# the track and the car's centre is at least 5 cm inside the nearer border, 1e-3 otherwise. A DeepRacer reward
# function: it runs unchanged in the DeepRacer console and DRfC.

MARGIN_M = 0.05
LOW = 1e-3


def reward_function(params):
    """1.0 on the road with a margin to the border, a token reward otherwise."""
    room = 0.5 * params["track_width"] - params["distance_from_center"]
    if params["all_wheels_on_track"] and room >= MARGIN_M:
        return 1.0
    return LOW
