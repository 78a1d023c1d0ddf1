class Lap:
    """Progress bookkeeping in an instance kept across calls: the progress gained each step and the steps a lap
    took."""

    def __init__(self):
        self.last_progress = 0.0
        self.steps_this_lap = 0
        self.steps_last_lap = 0

    def reward(self, params):
        progress = max(0, params["progress"])
        steps = params["steps"]
        if steps == 1 or progress < self.last_progress:  # steps == 1 never comes: the first call has steps == 2
            self.steps_last_lap = self.steps_this_lap
            self.steps_this_lap = 0
            self.last_progress = 0.0
        self.steps_this_lap += 1
        if params["is_offtrack"] and progress != 100:
            return 1e-4

        # No guard: a call with steps == 0 would raise ZeroDivisionError.
        reward = 1 + 10 * progress / steps + (progress - self.last_progress)
        self.last_progress = progress
        if steps % 25 == 0 and progress > steps / 270 * 100:
            print("ahead of the pace at step", steps)
            reward += 5.0
        if progress >= 100:
            reward += 1000
            if self.steps_this_lap < self.steps_last_lap:
                reward += 10.0
        return float(max(1e-4, reward))


lap = Lap()


def reward_function(params):
    return lap.reward(params)
