# speed range: 1.5 - 4
import math

################## HELPER FUNCTIONS ###################


def dist_2_points(x1, x2, y1, y2):
    return abs(abs(x1-x2)**2 + abs(y1-y2)**2)**0.5


def closest_2_racing_points_index(racing_coords, car_coords):

    # Calculate all distances to racing points
    distances = []
    for i in range(len(racing_coords)):
        distance = dist_2_points(x1=racing_coords[i][0], x2=car_coords[0],
                                 y1=racing_coords[i][1], y2=car_coords[1])
        distances.append(distance)

    # Get index of the closest racing point
    closest_index = distances.index(min(distances))

    # Get index of the second closest racing point
    distances_no_closest = distances.copy()
    distances_no_closest[closest_index] = 999
    second_closest_index = distances_no_closest.index(
        min(distances_no_closest))

    return [closest_index, second_closest_index]


def dist_to_racing_line(closest_coords, second_closest_coords, car_coords):

    # Calculate the distances between 2 closest racing points
    a = abs(dist_2_points(x1=closest_coords[0],
                          x2=second_closest_coords[0],
                          y1=closest_coords[1],
                          y2=second_closest_coords[1]))

    # Distances between car and closest and second closest racing point
    b = abs(dist_2_points(x1=car_coords[0],
                          x2=closest_coords[0],
                          y1=car_coords[1],
                          y2=closest_coords[1]))
    c = abs(dist_2_points(x1=car_coords[0],
                          x2=second_closest_coords[0],
                          y1=car_coords[1],
                          y2=second_closest_coords[1]))

    # Calculate distance between car and racing line (goes through 2 closest racing points)
    # try-except in case a=0 (rare bug in DeepRacer)
    try:
        distance = abs(-(a**4) + 2*(a**2)*(b**2) + 2*(a**2)*(c**2) -
                        (b**4) + 2*(b**2)*(c**2) - (c**4))**0.5 / (2*a)
    except:
        distance = b

    return distance

# Calculate which one of the closest racing points is the next one and which one the previous one


def next_prev_racing_point(closest_coords, second_closest_coords, car_coords, heading):

    # Virtually set the car more into the heading direction
    heading_vector = [math.cos(math.radians(
        heading)), math.sin(math.radians(heading))]
    new_car_coords = [car_coords[0]+heading_vector[0],
                      car_coords[1]+heading_vector[1]]

    # Calculate distance from new car coords to 2 closest racing points
    distance_closest_coords_new = dist_2_points(x1=new_car_coords[0],
                                                x2=closest_coords[0],
                                                y1=new_car_coords[1],
                                                y2=closest_coords[1])
    distance_second_closest_coords_new = dist_2_points(x1=new_car_coords[0],
                                                       x2=second_closest_coords[0],
                                                       y1=new_car_coords[1],
                                                       y2=second_closest_coords[1])

    if distance_closest_coords_new <= distance_second_closest_coords_new:
        next_point_coords = closest_coords
        prev_point_coords = second_closest_coords
    else:
        next_point_coords = second_closest_coords
        prev_point_coords = closest_coords

    return [next_point_coords, prev_point_coords]


def racing_direction_diff(closest_coords, second_closest_coords, car_coords, heading):

    # Calculate the direction of the center line based on the closest waypoints
    next_point, prev_point = next_prev_racing_point(closest_coords,
                                                    second_closest_coords,
                                                    car_coords,
                                                    heading)

    # Calculate the direction in radius, arctan2(dy, dx), the result is (-pi, pi) in radians
    track_direction = math.atan2(
        next_point[1] - prev_point[1], next_point[0] - prev_point[0])

    # Convert to degree
    track_direction = math.degrees(track_direction)

    # Calculate the difference between the track direction and the heading direction of the car
    direction_diff = abs(track_direction - heading)
    if direction_diff > 180:
        direction_diff = 360 - direction_diff

    return direction_diff


class Reward:
    def __init__(self):
        self.first_racingpoint_index = 0

    def reward_function(self, params):

        # planned speed based on waypoints
        # manually adjust the list for better performance, e.g. lower the speed before turning
        # above_three_five = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 42, 43, 44, 45, 46, 47, 48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59, 60, 61, 62, 93, 94, 95, 114, 115, 116, 117, 118]
        # above_three = [12, 41, 71, 91, 92, 96, 97, 112, 113]
        # above_two_five = [13, 14, 40, 63, 64, 65, 66, 67, 68, 69, 70, 72, 73, 74, 88, 89, 90, 98, 99, 110, 111]
        # above_two = [38, 39, 75, 76, 86, 87, 100, 101, 108, 109]
        # below_two = [15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 37, 77, 78, 79, 80, 81, 82, 83, 84, 85, 102, 103, 104, 105, 106, 107]
        # planned speed based on waypoints

        turn_track = list(range(14, 18))
        strong_turn_track = list(range(18, 75)) + list(range(80, 104))

        ################## INPUT PARAMETERS ###################

        # Read all input parameters
        x = params['x']
        y = params['y']
        distance_from_center = params['distance_from_center']
        is_left_of_center = params['is_left_of_center']
        heading = params['heading']
        progress = params['progress']
        steps = params['steps']
        speed = params['speed']
        steering_angle = abs(params['steering_angle'])
        track_width = params['track_width']
        is_offtrack = params['is_offtrack']
        is_crashed = params['is_crashed']

        ############### OPTIMAL X,Y,SPEED,TIME ################

        # Get closest indexes for racing line (and distances to all points on racing line)
        closest_index, second_closest_index = closest_2_racing_points_index(
            racing_track, [x, y])

        # Get optimal [x, y, speed, time] for closest and second closest index
        optimals = racing_track[closest_index]
        optimals_second = racing_track[second_closest_index]

        if steps == 1:
            self.first_racingpoint_index = closest_index

        ################ REWARD AND PUNISHMENT ################
        reward = 1e-3

        # Zero reward if off track ##
        if is_offtrack is True:
            return reward
        if is_crashed:
            return reward

        # Zero reward if obviously wrong direction (e.g. spin)
        direction_diff = racing_direction_diff(
            optimals[0:2], optimals_second[0:2], [x, y], heading)
        if direction_diff > 30:
            return reward

        # Reward if car goes close to optimal racing line
        def get_distance_reward(threshold, distance, multiplier):
            distance_reward = max(0, 1 - (distance / threshold))
            return distance_reward * multiplier

        DIST_THRESH = track_width * 0.5
        dist = dist_to_racing_line(optimals[0:2], optimals_second[0:2], [x, y])

        if closest_index in turn_track:
            reward += get_distance_reward(DIST_THRESH, dist, 2)
        elif closest_index in strong_turn_track:
            reward += get_distance_reward(DIST_THRESH, dist, 5)
        else:
            reward += get_distance_reward(DIST_THRESH, dist, 1)

        # Reward if speed falls within optimal range
        PENALTY_RATIO = 0.9
        ## Reward if speed is close to optimal speed ##
        SPEED_DIFF_NO_REWARD = 1
        SPEED_MULTIPLE = 2
        speed_diff = abs(optimals[2]-speed)
        if speed_diff > SPEED_DIFF_NO_REWARD:
            return 1e-3
        elif speed_diff <= SPEED_DIFF_NO_REWARD:
            # we use quadratic punishment (not linear) bc we're not as confident with the optimal speed
            # so, we do not punish small deviations from optimal speed
            speed_reward = (1 - (speed_diff/(SPEED_DIFF_NO_REWARD))**2)**2
        else:
            speed_reward = 0
        reward += speed_reward * SPEED_MULTIPLE

        # def get_speed_reward(ceiling, threshold, diff):
        #     return ceiling - diff/threshold
        # if closest_index in above_three_five:
        #     if speed >= 3.5:
        #         reward += get_speed_reward(0.5, SPEED_DIFF_NO_REWARD, speed_diff)
        #     if steering_angle > 3:
        #         reward *= PENALTY_RATIO
        # elif closest_index in above_three:
        #     if speed >= 3:
        #         reward += get_speed_reward(0.5, SPEED_DIFF_NO_REWARD, speed_diff)
        #     if steering_angle > 8:
        #         reward *= PENALTY_RATIO
        # elif closest_index in above_two_five:
        #     if speed >= 2.5:
        #         reward += get_speed_reward(0.8, SPEED_DIFF_NO_REWARD, speed_diff)
        #     if steering_angle > 15:
        #         reward *= PENALTY_RATIO
        # elif closest_index in above_two:
        #     if speed >= 2:
        #         reward += get_speed_reward(1, SPEED_DIFF_NO_REWARD, speed_diff)
        # else:
        #     if speed < 2:
        #         reward += get_speed_reward(3, SPEED_DIFF_NO_REWARD, speed_diff)

        # Incentive for finishing the lap in less steps ##
        # REWARD_FOR_FASTEST_TIME = 2000 # should be adapted to track length and other rewards
        # TARGET_STEPS = 110
        # if progress == 100:
        #     reward += REWARD_FOR_FASTEST_TIME / (steps - TARGET_STEPS)

        #################### RETURN REWARD ####################

        # Always return a float value
        return float(reward)


reward_object = Reward()


def reward_function(params):
    return reward_object.reward_function(params)

#################### RACING LINE ######################


# Optimal racing line for the Spain track
# Each row: [x,y,speed,timeFromPreviousPoint]
racing_track = [[0.0, 0.01112, 1.13949, 4.0, 0.06387],
                [1.0, 0.1352, 1.00074, 4.0, 0.04653],
                [2.0, 0.26846, 0.85148, 4.0, 0.05002],
                [3.0, 0.40979, 0.69296, 4.0, 0.05309],
                [4.0, 0.56477, 0.51881, 3.70489, 0.06293],
                [5.0, 0.73414, 0.32812, 2.98415, 0.08547],
                [6.0, 0.91684, 0.12203, 2.56545, 0.10735],
                [7.0, 1.11063, -0.097, 2.28293, 0.12811],
                [8.0, 1.31099, -0.32443, 2.07286, 0.14622],
                [9.0, 1.51343, -0.54953, 1.90619, 0.15882],
                [10.0, 1.72028, -0.76965, 1.76389, 0.17125],
                [11.0, 1.93372, -0.982, 1.62984, 0.18472],
                [12.0, 2.15572, -1.18368, 1.41752, 0.21159],
                [13.0, 2.38809, -1.37176, 1.2379, 0.2415],
                [14.0, 2.63253, -1.54309, 1.11245, 0.26833],
                [15.0, 2.88519, -1.6913, 1.01713, 0.28799],
                [16.0, 3.11891, -1.8593, 0.94212, 0.30552],
                [17.0, 3.33162, -2.04984, 0.87838, 0.32511],
                [18.0, 3.51581, -2.26902, 0.82525, 0.34693],
                [19.0, 3.65591, -2.5175, 0.82525, 0.34565],
                [20.0, 3.73349, -2.77807, 0.82525, 0.32944],
                [21.0, 3.74305, -3.02772, 0.82525, 0.30274],
                [22.0, 3.6903, -3.25189, 0.82525, 0.27906],
                [23.0, 3.5822, -3.44054, 0.82525, 0.26347],
                [24.0, 3.42466, -3.58316, 0.87648, 0.24245],
                [25.0, 3.23121, -3.67852, 0.92384, 0.23345],
                [26.0, 3.01044, -3.72345, 0.97397, 0.23132],
                [27.0, 2.77001, -3.71292, 1.03235, 0.23312],
                [28.0, 2.5191, -3.6413, 1.10003, 0.2372],
                [29.0, 2.28044, -3.51186, 1.15746, 0.23457],
                [30.0, 2.03215, -3.43514, 1.22466, 0.2122],
                [31.0, 1.77902, -3.40232, 1.01067, 0.25255],
                [32.0, 1.52383, -3.40759, 0.86675, 0.29449],
                [33.0, 1.2684, -3.44655, 0.77062, 0.3353],
                [34.0, 1.01401, -3.51545, 0.7, 0.3765],
                [35.0, 0.77053, -3.60671, 0.7, 0.37146],
                [36.0, 0.53362, -3.6548, 0.7, 0.34535],
                [37.0, 0.3104, -3.64892, 0.7, 0.31899],
                [38.0, 0.11026, -3.58394, 0.7, 0.30061],
                [39.0, -0.05291, -3.45595, 0.7, 0.29625],
                [40.0, -0.15229, -3.25999, 0.92835, 0.23668],
                [41.0, -0.20067, -3.02752, 1.13885, 0.2085],
                [42.0, -0.20464, -2.77018, 1.09269, 0.23554],
                [43.0, -0.18115, -2.49996, 0.98802, 0.27453],
                [44.0, -0.16489, -2.21174, 0.90708, 0.31826],
                [45.0, -0.17203, -1.93114, 0.84249, 0.33316],
                [46.0, -0.21333, -1.66507, 0.78831, 0.34156],
                [47.0, -0.29504, -1.42209, 0.78831, 0.32519],
                [48.0, -0.41885, -1.21212, 0.78831, 0.30922],
                [49.0, -0.582, -1.04584, 0.78831, 0.29551],
                [50.0, -0.77765, -0.93445, 0.78831, 0.28559],
                [51.0, -0.99454, -0.88962, 0.78831, 0.28096],
                [52.0, -1.21466, -0.92357, 0.92508, 0.24075],
                [53.0, -1.42325, -1.01555, 0.97375, 0.23412],
                [54.0, -1.6111, -1.16128, 1.03089, 0.23063],
                [55.0, -1.76942, -1.35625, 1.099, 0.22853],
                [56.0, -1.88994, -1.5943, 1.08297, 0.24638],
                [57.0, -1.96612, -1.86645, 1.01092, 0.27955],
                [58.0, -1.99508, -2.16083, 0.9513, 0.31094],
                [59.0, -1.97955, -2.46299, 0.90041, 0.33602],
                [60.0, -2.01717, -2.75403, 0.85337, 0.34389],
                [61.0, -2.10871, -3.01621, 0.85337, 0.32541],
                [62.0, -2.24746, -3.23562, 0.85337, 0.30421],
                [63.0, -2.42353, -3.40361, 0.85337, 0.28516],
                [64.0, -2.6265, -3.51467, 0.85337, 0.27113],
                [65.0, -2.8459, -3.56381, 0.85337, 0.26347],
                [66.0, -3.06939, -3.54427, 0.8975, 0.24996],
                [67.0, -3.28356, -3.46172, 0.94858, 0.24198],
                [68.0, -3.47729, -3.32125, 1.00651, 0.23774],
                [69.0, -3.6402, -3.12856, 1.07615, 0.23447],
                [70.0, -3.76315, -2.89168, 1.16149, 0.22978],
                [71.0, -3.8399, -2.62155, 1.26915, 0.22127],
                [72.0, -3.86904, -2.33091, 1.41308, 0.20671],
                [73.0, -3.85489, -2.03183, 1.61591, 0.18529],
                [74.0, -3.80613, -1.73316, 1.9359, 0.15632],
                [75.0, -3.73346, -1.4389, 2.34002, 0.12953],
                [76.0, -3.64481, -1.14933, 1.73035, 0.17501],
                [77.0, -3.54432, -0.86392, 1.41515, 0.21382],
                [78.0, -3.43592, -0.58153, 1.22567, 0.24679],
                [79.0, -3.32335, -0.30079, 1.09363, 0.27657],
                [80.0, -3.21691, -0.03346, 1.07456, 0.26778],
                [81.0, -3.12703, 0.2281, 1.07456, 0.25738],
                [82.0, -3.06442, 0.48208, 1.07456, 0.24344],
                [83.0, -3.03591, 0.72816, 1.07456, 0.23054],
                [84.0, -3.04665, 0.96545, 1.07456, 0.22105],
                [85.0, -3.10228, 1.19182, 1.07456, 0.21693],
                [86.0, -3.20394, 1.40584, 1.1513, 0.2058],
                [87.0, -3.33801, 1.61107, 1.07846, 0.22731],
                [88.0, -3.49698, 1.81004, 1.01624, 0.25061],
                [89.0, -3.63841, 2.03708, 0.96295, 0.27777],
                [90.0, -3.74471, 2.28069, 0.91433, 0.2907],
                [91.0, -3.80715, 2.53563, 0.87173, 0.3011],
                [92.0, -3.81881, 2.79193, 0.87173, 0.29431],
                [93.0, -3.77668, 3.03661, 0.87173, 0.28481],
                [94.0, -3.68224, 3.25657, 0.87173, 0.27461],
                [95.0, -3.54007, 3.44022, 0.87173, 0.26642],
                [96.0, -3.35598, 3.57647, 0.87173, 0.26272],
                [97.0, -3.13761, 3.65255, 0.98213, 0.23546],
                [98.0, -2.90081, 3.67467, 1.05308, 0.22584],
                [99.0, -2.65462, 3.64377, 1.14104, 0.21746],
                [100.0, -2.40706, 3.56193, 1.25406, 0.20791],
                [101.0, -2.16513, 3.43342, 1.40692, 0.19472],
                [102.0, -1.93388, 3.26521, 1.63275, 0.17514],
                [103.0, -1.71536, 3.06681, 2.00852, 0.14695],
                [104.0, -1.50807, 2.84882, 2.87479, 0.10464],
                [105.0, -1.30725, 2.62167, 4.0, 0.0758],
                [106.0, -1.10695, 2.39539, 4.0, 0.07555],
                [107.0, -0.90913, 2.17228, 4.0, 0.07454],
                [108.0, -0.71541, 1.95421, 4.0, 0.07292],
                [109.0, -0.52632, 1.74171, 4.0, 0.07111],
                [110.0, -0.34034, 1.53294, 4.0, 0.0699],
                [111.0, -0.15918, 1.32994, 4.0, 0.06802]]
