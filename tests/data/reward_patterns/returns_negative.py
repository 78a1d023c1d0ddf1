def reward_function(params):
    # Negative rewards: a bare -5.0 (no float()) off the track, and int arithmetic that can go below zero.
    if params["is_offtrack"] or params["is_crashed"]:
        return -5.0
    reward = 1e-3
    if params["all_wheels_on_track"] and 0.5 * params["track_width"] - params["distance_from_center"] >= 0.05:
        reward = 31
    if abs(params["steering_angle"]) > 0:
        reward -= 15  # 16 when steering, or -14.999 near the edge
    return float(reward)
