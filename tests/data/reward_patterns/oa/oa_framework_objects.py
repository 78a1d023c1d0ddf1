import math

STEPS_PER_SECOND = 15


class Tracker:
    """Built on the first call, updated by every call: which object is ahead, which behind, when each was passed."""

    def __init__(self, params):
        self.waypoint_count = len(params["waypoints"])
        self.steps = 0
        self.front = None
        self.rear = None
        self.previous_front = -1
        self.passed_at = [-1] * 20
        self.front_gap = None
        self.rear_gap = None
        self.hit_distance = None

    @staticmethod
    def ray_hit(x, y, heading, box, radius=0.3):
        # Distance along the heading to where the car's path comes within radius of the box's centre, if it does.
        hx, hy = math.cos(math.radians(heading)), math.sin(math.radians(heading))
        along = (box[0] - x) * hx + (box[1] - y) * hy
        if along <= 0:
            return None
        across = abs((box[0] - x) * hy - (box[1] - y) * hx)
        if across > radius:
            return None
        return along - math.sqrt(radius**2 - across**2)

    def update(self, params):
        self.steps = int(round(params["steps"]))
        locations = params["objects_location"]
        if self.steps == 2 and len(locations) > 0:
            print("DRG-OBJECTS:", locations)  # read by log tools as a list of [x, y]
        if self.steps <= 2:
            self.passed_at = [-1] * 20
            self.previous_front = -1
        if not locations:
            self.front = self.rear = self.front_gap = self.rear_gap = self.hit_distance = None
            return
        car = (params["x"], params["y"])
        self.front = int(params["closest_objects"][1])
        self.rear = int(params["closest_objects"][0])
        if self.rear == self.previous_front:
            self.passed_at[self.rear] = self.steps
        self.previous_front = self.front
        self.front_gap = math.dist(car, locations[self.front])
        self.rear_gap = math.dist(car, locations[self.rear])
        self.hit_distance = self.ray_hit(car[0], car[1], params["heading"], locations[self.front])
        if self.hit_distance is None and len(locations) > 1:
            second = (self.front + 1) % len(locations)
            self.hit_distance = self.ray_hit(car[0], car[1], params["heading"], locations[second])


def reward_function(params):
    global tracker
    if not tracker:
        tracker = Tracker(params)
    tracker.update(params)
    reward = 1.0 if params["all_wheels_on_track"] else 1e-3
    if tracker.hit_distance is not None:
        reward *= min(1.0, 0.2 + tracker.hit_distance / 2)
    if tracker.front_gap is not None and tracker.front_gap < 0.5:
        reward *= 0.5
    return float(reward)


tracker = None
