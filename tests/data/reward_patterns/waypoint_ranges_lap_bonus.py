class Reward:
    """Bonuses by ranges of waypoint indices, a count of repeated steering kept across calls, and a lap bonus in the
    tens of thousands (DeepRacer stops a run only beyond 1e5)."""

    def __init__(self):
        self.last_steering = 0
        self.repeats = 0

    def get_reward(self, params):
        if not params["is_offtrack"] and params["steps"] > 0:
            waypoint = params["closest_waypoints"][0]
            speed = params["speed"]
            steering = params["steering_angle"]
            bonus = 0
            side = 0
            if waypoint < 12 or waypoint > 105 or (waypoint > 44 and waypoint < 68):
                if steering == 0:
                    bonus = 30 if speed >= 3.5 else 10
                elif speed > 2:
                    bonus = 5
                if params["is_left_of_center"]:
                    side = 40
            elif (waypoint >= 14 and waypoint <= 38) or (waypoint >= 80 and waypoint <= 100):
                if steering > 0:
                    if speed > 2.5:
                        bonus = 20
                    elif speed > 1.5:
                        bonus = 12
                    else:
                        bonus = 6
                if params["is_left_of_center"]:
                    side = 100
            else:
                bonus = 2
            repeat_bonus = 20 * min(10, self.repeats) if steering == self.last_steering else 0
            if steering == self.last_steering:
                self.repeats += 1
            else:
                self.last_steering = steering
                self.repeats = 0
            lap_bonus = 0
            if params["progress"] == 100:
                if params["steps"] < 100:
                    lap_bonus = 45000
                elif params["steps"] < 150:
                    lap_bonus = 30000
                else:
                    lap_bonus = 10000
            return float(0.00001 + bonus * 10 + side + repeat_bonus + lap_bonus)
        return 0.00001


reward = Reward()


def reward_function(params):
    return reward.get_reward(params)
