import math


class Memory:
    """State kept in class attributes (no instance), reset when the step count goes down."""

    last_steps = None
    last_speed = None
    slowing_into = None


LOOK_AHEAD = 6


def heading_to(a, b):
    return math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))


def reward_function(params):
    steps = params["steps"]
    speed = params["speed"]
    waypoints = params["waypoints"]
    n = len(waypoints)
    if Memory.last_steps is None or steps < Memory.last_steps:  # a new episode
        Memory.last_speed = None
        Memory.slowing_into = None

    here = params["closest_waypoints"][1]
    ahead = (here + LOOK_AHEAD) % n
    bend = abs(
        (heading_to(waypoints[ahead], waypoints[(ahead + 1) % n]) - heading_to(waypoints[here], waypoints[ahead]) + 180)
        % 360
        - 180
    )
    braking = Memory.last_speed is not None and speed < Memory.last_speed

    reward = params["progress"] / steps * 50 + speed**2
    if bend > 25:
        if braking:
            reward *= 1.25
            Memory.slowing_into = ahead
    elif Memory.slowing_into is not None and here == Memory.slowing_into:
        Memory.slowing_into = None

    Memory.last_speed = speed
    Memory.last_steps = steps
    if params["is_offtrack"]:
        return 1e-3
    return float(reward)
