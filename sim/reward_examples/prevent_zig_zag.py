# racer's reward function against zig-zagging, written for racer with the rewards of the third example in AWS
# DeepRacer's developer guide ("prevent zig-zag in time trials"): the centre-line bands of follow_center_line.py
# (1.0 / 0.5 / 0.1 within 10 / 25 / 50 % of the track width, 1e-3 beyond), times 0.8 when the steering angle's
# size is over 15 degrees. A DeepRacer reward function: it runs unchanged in the DeepRacer console and DRfC.

BANDS = ((0.1, 1.0), (0.25, 0.5), (0.5, 0.1))  # (share of the track width from the centre line, reward)
OFF_ROAD = 1e-3
STEERING_LIMIT_DEG = 15  # set it to your action space: steering beyond it is penalised
STEERING_PENALTY = 0.8


def reward_function(params):
    """The centre-line band's reward, cut when the car steers hard."""
    distance = params["distance_from_center"]
    width = params["track_width"]
    reward = next((r for share, r in BANDS if distance <= share * width), OFF_ROAD)
    if abs(params["steering_angle"]) > STEERING_LIMIT_DEG:
        reward *= STEERING_PENALTY
    return float(reward)
