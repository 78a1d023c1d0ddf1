import numpy as np
from scipy import spatial
from shapely.geometry import LineString, Point


def reward_function(params):
    line = LineString(params["waypoints"])
    car = Point(params["x"], params["y"])
    tree = spatial.cKDTree(np.asarray(params["waypoints"]))
    dist, _ = tree.query([params["x"], params["y"]])
    off = line.distance(car)
    return float(np.exp(-5.0 * off) + 0.1 * np.exp(-dist))
