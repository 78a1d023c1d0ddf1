import math
import time


def yes_no(flag):
    return "yes" if flag else "no"


class State:
    def __init__(self, params):
        self.on_track = params["all_wheels_on_track"]
        self.x, self.y = params["x"], params["y"]
        self.gap = params["distance_from_center"]
        self.left = params["is_left_of_center"]
        self.heading = params["heading"]
        self.speed = params["speed"]
        self.steering = params["steering_angle"]
        self.width = params["track_width"]
        self.waypoints = params["waypoints"]
        self.closest = params["closest_waypoints"]


class Car:
    MAX_SPEED = 1.0
    MAX_STEER = 30.0

    def __init__(self, state):
        self.state = state
        a = state.waypoints[state.closest[0]]
        b = state.waypoints[state.closest[1]]
        along = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
        self.aligned = abs(along - state.heading) < 10.0  # no wrap at +-180, as written
        self.centred = state.gap <= 0.1 * state.width
        self.near_centre = state.gap <= 0.25 * state.width
        self.fast = state.speed > 0.9 * self.MAX_SPEED
        self.hard_turn = abs(state.steering) > 0.9 * self.MAX_STEER
        self.returning = (state.left and state.steering < 0) or (not state.left and state.steering > 0)


class Rules:
    LEVELS = {"top": 1.0, "good": 0.7, "some": 0.4, "base": 0.1, "penalty": -1.0}

    def __init__(self, car):
        self.car = car
        self.rule, self.level = 0, "base"

    def apply(self):
        car = self.car
        if car.near_centre and not car.hard_turn:
            self.rule, self.level = 1, "some"
        if car.state.on_track and not car.near_centre and car.returning:
            self.rule, self.level = 2, "some"
        if car.centred and car.aligned and car.fast:
            self.rule, self.level = 3, "top"
        if car.fast and car.hard_turn:
            self.rule, self.level = 4, "penalty"
        if not car.state.on_track:
            self.rule, self.level = 5, "penalty"
        return self.LEVELS.get(self.level)

    def trace(self):
        s = self.car.state
        print("TRACE_STATUS", time.time(), yes_no(s.on_track), s.x, s.y, s.gap, yes_no(s.left), self.rule, self.level)
        line = "TRACE_WAYPOINTS"
        for count, [x, y] in enumerate(s.waypoints):  # each waypoint unpacked as a pair
            line += f" {count} {x} {y}"
        print(line)


def reward_function(params):
    rules = Rules(Car(State(params)))  # new objects on every call
    score = rules.apply()
    rules.trace()
    return float(score)
