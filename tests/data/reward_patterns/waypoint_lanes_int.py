# Lanes and speeds by waypoint index, written for racer_loop (118 waypoints); an int reward, never float().
INSIDE_LANE = [14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 37, 38]
INSIDE_LANE += list(range(80, 101))
OUTSIDE_LANE = [4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 70, 71, 72, 73, 74, 75, 76, 77, 78, 79]
CENTRE_LANE = [i for i in range(118) if i not in INSIDE_LANE and i not in OUTSIDE_LANE]
FAST = list(range(0, 14)) + list(range(44, 70)) + list(range(103, 118))
SLOW = list(range(20, 36)) + list(range(84, 98))


def reward_function(params):
    nxt = params["closest_waypoints"][1]
    left = params["is_left_of_center"]
    spread = params["distance_from_center"] / params["track_width"]
    speed = params["speed"]

    reward = 21
    if nxt in INSIDE_LANE and left:
        print("inside lane")
        reward += 10
    elif nxt in OUTSIDE_LANE and not left:
        print("outside lane")
        reward += 10
    elif nxt in CENTRE_LANE and spread < 0.35:
        reward += 10
    else:
        reward -= 10

    if nxt in FAST:
        reward += 20 if speed >= 3 else -10
    elif nxt in SLOW:
        if speed < 2.4:
            reward += 10
        elif speed <= 3:
            reward += 5
        else:
            reward -= 10
    if params["is_offtrack"]:
        reward = 1
    return reward
