import math


class Reward:
    def __init__(self):
        self.first_index = None
        self.calls = 0

    def reward_function(self, params):
        self.calls += 1
        if self.first_index is None:
            self.first_index = params["closest_waypoints"][1]
        n = len(params["waypoints"])
        ahead = params["waypoints"][(params["closest_waypoints"][1] + 3) % n]
        heading = math.degrees(math.atan2(ahead[1] - params["y"], ahead[0] - params["x"]))
        diff = abs((heading - params["heading"] + 180) % 360 - 180)
        return max(1e-3, 1.0 - diff / 180.0) * (1.0 if params["all_wheels_on_track"] else 1e-3)


reward_object = Reward()


def reward_function(params):
    return reward_object.reward_function(params)
