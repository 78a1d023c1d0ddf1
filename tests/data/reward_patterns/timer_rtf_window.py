import time

import numpy


class Timer:
    """A window of (wall clock, simulation clock) pairs by step, kept in one instance across calls and episodes."""

    def __init__(self, window=12, verbose=False):
        self.samples = numpy.zeros([window, 2])
        self.episode_start = None
        self.last_steps = None
        self.verbose = verbose
        if verbose:
            print("timer ready")

    def record(self, steps, sim_time):
        row = int(steps) % self.samples.shape[0]
        self.samples[row, 0] = time.time()
        self.samples[row, 1] = sim_time

    def rates(self):
        wall = numpy.max(self.samples[:, 0]) - numpy.min(self.samples[:, 0])
        sim = numpy.max(self.samples[:, 1]) - numpy.min(self.samples[:, 1])
        rtf = sim / wall if wall > 0 else 0.0
        fps = (self.samples.shape[0] - 1) / sim if sim > 0 else 0.0
        return rtf, fps

    def reward_function(self, params):
        steps = params["steps"]
        if self.last_steps is None or steps < self.last_steps:
            # DeepRacer's docs mention no 'timestamp' key: fall back on the wall clock
            self.episode_start = params.get("timestamp", None) or time.time()
        self.last_steps = steps
        self.record(steps, params.get("sim_time", 0.0))
        if steps >= self.samples.shape[0]:
            rtf, fps = self.rates()
            if self.verbose:
                print(f"TIME: steps {int(steps)} rtf {round(rtf, 2)} fps {round(fps, 2)}")
        return 0.7 if abs(params["steering_angle"]) > 14 else 1.0


timer = Timer(verbose=True)


def reward_function(params):
    return timer.reward_function(params)
