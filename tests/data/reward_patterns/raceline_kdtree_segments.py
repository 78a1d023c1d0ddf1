import numpy as np
from scipy.spatial import KDTree
from shapely.geometry import LineString, Point


class Reward:
    """A racing line and the borders as numpy arrays, a KD-tree built once at import, per-segment records kept
    across episodes."""

    def __init__(self, race_line, inner, outer, segments=10, verbose=1):
        self.tree = KDTree(race_line)
        self.inner = LineString(inner)
        self.outer = LineString(outer)
        self.segments = segments
        self.verbose = verbose
        self.steering = [0.0] * 3
        self.slot = 0
        self.segment = None
        self.segment_steps = 0
        self.segment_speeds = []
        self.step_records = [np.inf] * segments
        self.time_records = [np.inf] * segments
        self.lap = {"steps": 0, "speeds": [], "best": np.inf}
        self.last_progress = 0.0
        self.went_off = False

    def log(self, level, *message):
        if level <= self.verbose:
            print(*message)

    def segment_of(self, index, waypoints):
        size = len(waypoints) / self.segments
        for i in range(1, self.segments + 1):
            if index < int(i * size):
                return i - 1
        return self.segments - 1

    def heading_score(self, x, y, heading):
        _, nearest = self.tree.query([x, y], k=1)
        # The module's race line, not an attribute: the method reads the global at call time.
        target = RACE_LINE[(nearest + 2) % len(RACE_LINE)]
        wanted = np.degrees(np.arctan2(target[1] - y, target[0] - x))
        diffs = [abs((wanted - h + 180) % 360 - 180) for h in (heading, heading + 180)]
        return max(0.0, (60 - min(diffs)) / 60)

    def smoothness(self, steering_angle):
        self.steering[self.slot] = steering_angle
        self.slot = (self.slot + 1) % len(self.steering)
        return 1 - (max(self.steering) - min(self.steering)) / 60

    def close_segment(self, segment, progress):
        bonus = 0.0
        if self.segment is None or self.went_off or progress < 100 / self.segments - 1:
            self.log(2, "segment", segment, "started part way or after a reset: no record")
        elif segment == (self.segment + 1) % self.segments and self.segment_speeds:
            seconds = len(self.segment_speeds) / np.mean(self.segment_speeds)
            if self.segment_steps <= self.step_records[segment - 2]:
                self.step_records[segment - 2] = self.segment_steps
                bonus += 5.0
            if seconds <= self.time_records[segment - 2]:
                self.time_records[segment - 2] = seconds
                bonus += 10.0
                self.log(1, "new time record for segment", segment, round(seconds, 2))
        self.segment_steps = 0
        self.segment_speeds = []
        self.went_off = False
        return bonus

    def reward_function(self, params):
        car = Point(params["x"], params["y"])
        speed = params["speed"]
        progress = params["progress"]
        if params["is_offtrack"]:
            self.went_off = True
        segment = self.segment_of(params["closest_waypoints"][0], params["waypoints"])
        bonus = self.close_segment(segment, progress) if segment != self.segment else 0.0
        self.segment = segment
        self.segment_steps += 1
        self.segment_speeds.append(speed)

        if progress < self.last_progress:
            self.lap["steps"], self.lap["speeds"] = 0, []
        self.last_progress = progress
        self.lap["steps"] += 1
        self.lap["speeds"].append(speed)

        margin = min(car.distance(self.inner), car.distance(self.outer))
        reward = 2 * self.heading_score(car.x, car.y, params["heading"])
        reward += 0.5 * self.smoothness(params["steering_angle"]) + bonus + min(margin, 0.3)
        if progress == 100:
            seconds = self.lap["steps"] / np.mean(self.lap["speeds"])
            self.lap["best"] = min(self.lap["best"], seconds)
            self.log(1, "lap in", self.lap["steps"], "steps")
            reward += 100
        if params["is_offtrack"]:
            reward = -10
        return float(reward)


# The racing line and borders of racer_loop, every third point, as [x, y] rows.
RACE_LINE = np.array(
    [
        [4.0819, 1.2034],
        [4.5112, 1.2359],
        [4.9399, 1.2731],
        [5.3682, 1.3152],
        [5.7964, 1.3615],
        [6.2248, 1.4108],
        [6.6508, 1.4687],
        [7.0560, 1.5729],
        [7.4247, 1.7349],
        [7.7284, 1.9653],
        [7.9075, 2.2690],
        [7.8859, 2.6077],
        [7.6808, 2.9081],
        [7.3703, 3.1454],
        [7.0030, 3.3261],
        [6.6031, 3.4601],
        [6.1844, 3.5585],
        [5.7630, 3.6488],
        [5.3416, 3.7371],
        [4.9198, 3.8229],
        [4.4974, 3.9068],
        [4.0739, 3.9873],
        [3.6491, 4.0294],
        [3.2277, 4.0175],
        [2.8168, 3.9476],
        [2.4250, 3.8184],
        [2.0623, 3.6308],
        [1.7390, 3.3890],
        [1.4661, 3.0992],
        [1.2596, 2.7684],
        [1.1485, 2.4068],
        [1.1714, 2.0403],
        [1.3415, 1.7139],
        [1.6255, 1.4602],
        [1.9796, 1.2838],
        [2.3739, 1.1782],
        [2.7913, 1.1361],
        [3.2210, 1.1494],
        [3.6519, 1.1750],
    ]
)
INNER = np.array(
    [
        [3.9785, 1.4294],
        [4.4511, 1.5333],
        [4.9640, 1.5684],
        [5.4311, 1.5475],
        [5.8634, 1.5326],
        [6.2805, 1.5482],
        [6.6838, 1.6049],
        [7.0648, 1.7099],
        [7.4038, 1.8688],
        [7.6638, 2.0791],
        [7.7938, 2.3108],
        [7.7801, 2.5417],
        [7.6224, 2.7876],
        [7.3479, 3.0105],
        [7.0044, 3.1887],
        [6.6212, 3.3236],
        [6.2124, 3.4236],
        [5.7817, 3.5026],
        [5.3292, 3.5822],
        [4.8708, 3.6830],
        [4.4363, 3.7902],
        [4.0235, 3.8714],
        [3.6187, 3.9089],
        [3.2190, 3.8951],
        [2.8293, 3.8263],
        [2.4577, 3.7013],
        [2.1133, 3.5204],
        [1.8060, 3.2868],
        [1.5482, 3.0071],
        [1.3596, 2.6951],
        [1.2662, 2.3745],
        [1.2867, 2.0734],
        [1.4243, 1.8044],
        [1.6685, 1.5787],
        [1.9900, 1.4114],
        [2.3574, 1.3069],
        [2.7488, 1.2624],
        [3.1506, 1.2727],
        [3.5574, 1.3318],
    ]
)
OUTER = np.array(
    [
        [4.1616, 0.6917],
        [4.5699, 0.7827],
        [4.9564, 0.8085],
        [5.3908, 0.7886],
        [5.8604, 0.7726],
        [6.3450, 0.7910],
        [6.8349, 0.8600],
        [7.3232, 0.9952],
        [7.7994, 1.2199],
        [8.2357, 1.5786],
        [8.5325, 2.1321],
        [8.4985, 2.7898],
        [8.1805, 3.3035],
        [7.7580, 3.6503],
        [7.3018, 3.8881],
        [6.8342, 4.0531],
        [6.3667, 4.1678],
        [5.9096, 4.2518],
        [5.4733, 4.3284],
        [5.0503, 4.4215],
        [4.6085, 4.5304],
        [4.1358, 4.6230],
        [3.6424, 4.6685],
        [3.1408, 4.6510],
        [2.6425, 4.5630],
        [2.1596, 4.4004],
        [1.7058, 4.1619],
        [1.2956, 3.8499],
        [0.9428, 3.4666],
        [0.6666, 3.0072],
        [0.5114, 2.4637],
        [0.5544, 1.8703],
        [0.8230, 1.3396],
        [1.2370, 0.9531],
        [1.7137, 0.7034],
        [2.2130, 0.5607],
        [2.7176, 0.5030],
        [3.2174, 0.5157],
        [3.7034, 0.5860],
    ]
)

reward_object = Reward(RACE_LINE, INNER, OUTER)


def reward_function(params):
    return reward_object.reward_function(params)
