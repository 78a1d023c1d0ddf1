import math


def densify(points, factor):
    dense = []
    for i in range(len(points)):
        a, b = points[i], points[(i + 1) % len(points)]
        for k in range(factor):
            t = k / factor
            dense.append((a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t))
    return dense


def reward_function(params):
    waypoints = list(params["waypoints"])
    if params["is_reversed"]:
        waypoints.reverse()  # written for waypoints that stay in the track's own order
    dense = densify(waypoints, 20)
    car = (params["x"], params["y"])
    nearest = min(range(len(dense)), key=lambda i: math.dist(dense[i], car))
    ahead = dense[nearest:] + dense[:nearest]
    inside = [math.dist(p, car) < 0.9 * params["track_width"] for p in ahead]
    target = ahead[inside.index(False)]  # ValueError if every point were within the circle
    wanted = math.degrees(math.atan2(target[1] - car[1], target[0] - car[0]))
    steer = (wanted - params["heading"] + 180) % 360 - 180
    score = max(0.0, 1 - abs(steer - params["steering_angle"]) / 60)

    avoid = 1.0
    if params["objects_location"]:
        nxt = params["closest_objects"][1]
        gap = math.dist(car, params["objects_location"][nxt])
        if params["objects_left_of_center"][nxt] == params["is_left_of_center"]:
            if gap < 0.4:
                avoid = 0.2
            elif gap < 0.8:
                avoid = 0.5
    return float(score + 4 * avoid)
