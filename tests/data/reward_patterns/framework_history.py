import math

STEPS_PER_SECOND = 15
CAR_WIDTH = 0.2


def bearing(a, b):
    return math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))


def turn(current, wanted):
    return (wanted - current + 180) % 360 - 180


class Step:
    def __init__(self, x, y, progress, speed, steering, previous):
        self.x, self.y = x, y
        self.progress = progress
        self.speed = speed
        self.steering = steering
        self.distance = 0.0 if previous is None else math.hypot(x - previous.x, y - previous.y)


class Framework:
    """Built once, on the first call, from that call's waypoints; then updated by every call."""

    def __init__(self, params):
        self.edges = self.edge_points(params["waypoints"], params["track_width"])
        self.history = []
        self.steps = 0
        self.progress_speed = 0.0
        self.sequence = 0
        self.front_object = None
        self.passed_object_at = {}

    @staticmethod
    def edge_points(waypoints, width):
        # Tracks repeat their first waypoint as the last, and some repeat points in between: skip the repeats.
        previous = waypoints[-2] if waypoints[0] == waypoints[-1] else waypoints[-1]
        edges = []
        for i, point in enumerate(waypoints):
            if point != previous:
                following = waypoints[(i + 1) % len(waypoints)]
                direction = bearing(previous, point) + turn(bearing(previous, point), bearing(point, following)) / 2
                reach = width / 2 + CAR_WIDTH / 2
                left = (
                    point[0] + reach * math.cos(math.radians(direction + 90)),
                    point[1] + reach * math.sin(math.radians(direction + 90)),
                )
                right = (
                    point[0] + reach * math.cos(math.radians(direction - 90)),
                    point[1] + reach * math.sin(math.radians(direction - 90)),
                )
                edges.append((left, right))
                previous = point
            else:
                edges.append(edges[-1] if edges else (point, point))
        return edges

    def update(self, params):
        self.steps = int(round(params["steps"]))
        if self.steps <= 2:  # the first rewarded step of an episode is step 2
            self.history = []
            self.passed_object_at = {}
        previous = self.history[-1] if self.history else None
        step = Step(
            float(params["x"]),
            float(params["y"]),
            float(params["progress"]),
            params["speed"],
            params["steering_angle"],
            previous,
        )
        self.history.append(step)
        if previous is not None and (previous.speed, previous.steering) == (step.speed, step.steering):
            self.sequence += 1
        else:
            self.sequence = 1
        recent = self.history[-6:]
        if len(recent) > 1:
            travelled = (step.progress - recent[0].progress) / 100 * params["track_length"]
            self.progress_speed = max(0.0, travelled / ((len(recent) - 1) / STEPS_PER_SECOND))
        else:
            self.progress_speed = 0.0
        self.predicted_lap_time = (
            round(100 / step.progress * self.steps / STEPS_PER_SECOND, 2) if step.progress > 0 else 0.0
        )

        # Object-avoidance bookkeeping: in a time trial the lists are empty.
        locations = params["objects_location"]
        if len(locations) > 0:
            behind, ahead = int(params["closest_objects"][0]), int(params["closest_objects"][1])
            if behind == self.front_object:
                self.passed_object_at[behind] = self.steps
            self.front_object = ahead
        else:
            self.front_object = None


def reward_function(params):
    global framework
    if not framework:
        framework = Framework(params)
    framework.update(params)
    raw = framework.progress_speed / 4.0 + framework.steps / 1000 - (0.0 if params["all_wheels_on_track"] else 1.0)
    if raw > 0:
        return float(raw)
    print("WARNING - reward " + str(raw) + " replaced with 0.0001")
    return 0.0001


framework = None
