# Does not parse on any Python: the dict below misses a comma after its second entry.
WEIGHTS = {
    "heading": 2.0,
    "smoothness": 0.5
    "progress": 1.0,
}


def reward_function(params):
    return WEIGHTS["heading"] * float(params["all_wheels_on_track"])
