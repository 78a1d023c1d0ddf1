"""``racer bench env``: env steps per second on one core, and where the time goes."""

from __future__ import annotations

import contextlib
import os
import platform
import statistics
import time
from collections.abc import Callable

import cv2
import numpy as np

from common.config import EnvConfig
from sim.env import RacerEnv


def pin_to_one_core() -> int | None:
    """Run this process on one CPU core with single-threaded OpenCV; returns the core, or None if unsupported."""
    cv2.setNumThreads(1)
    with contextlib.suppress(ImportError):
        import torch

        torch.set_num_threads(1)  # two OpenMP threads spinning on one core are many times slower than one
    if not hasattr(os, "sched_setaffinity"):
        return None
    core = sorted(os.sched_getaffinity(0))[-1]
    os.sched_setaffinity(0, {core})
    return core


def _timed_steps(env: RacerEnv, steps: int, rng: np.random.Generator) -> float:
    """Seconds for ``steps`` env.step calls with random actions (resets excluded from the clock)."""
    env.reset(seed=int(rng.integers(1 << 31)))
    total = 0.0
    for _ in range(steps):
        action = env.action_space.sample()
        t0 = time.perf_counter()
        _, _, term, trunc, _ = env.step(action)
        total += time.perf_counter() - t0
        if term or trunc:
            env.reset()
    return total


def _physics_us(env: RacerEnv, steps: int) -> float:
    """Microseconds per control step of the physics alone, driven by random actions as in training."""
    env.reset(seed=0)
    total = 0.0
    for i in range(steps):
        command = env.actions.command(env.action_space.sample())
        t0 = time.perf_counter()
        env.physics.command(*command)
        env.physics.step()
        total += time.perf_counter() - t0
        if i % 60 == 59:  # a fresh start now and then, as episodes end
            env.reset()
    return total / steps * 1e6


def _parts(env: RacerEnv, steps: int) -> dict[str, float]:
    """Microseconds per step of each part, timed separately on the same code the env runs."""
    out = {"physics": _physics_us(env, steps)}
    env.reset(seed=0)
    ph, task = env.physics, env.task
    command = env.actions.command(env.action_space.sample())
    result = task.observe(ph.pose, ph.wheel_positions(), True, ph.time, command)

    def task_step() -> None:
        task.observe(ph.pose, ph.wheel_positions(), ph.upright, ph.time, command)

    def reward() -> None:
        env.reward_fn(result.params, step=1)

    def camera() -> None:
        env._observe()

    parts: dict[str, Callable[[], None]] = {"camera": camera, "task": task_step, "reward": reward}
    for name, fn in parts.items():
        t0 = time.perf_counter()
        for _ in range(steps):
            fn()
        out[name] = (time.perf_counter() - t0) / steps * 1e6
    return out


def bench_env(config: EnvConfig, steps: int = 2000, repeats: int = 5, seed: int = 0) -> dict:
    """Measure env steps/s (physics + camera + task + reward) on one core; medians over ``repeats`` runs."""
    core = pin_to_one_core()
    env = RacerEnv(config=config)
    env.action_space.seed(seed)
    rng = np.random.default_rng(seed)
    _timed_steps(env, 200, rng)  # warm caches and allocators
    rates = [steps / _timed_steps(env, steps, rng) for _ in range(repeats)]
    parts = [_parts(env, max(200, steps // 4)) for _ in range(repeats)]
    env.close()
    result: dict = {
        "steps_per_s": statistics.median(rates),
        "steps_per_s_runs": [round(r, 1) for r in rates],
        "track": config.track,
        "camera": config.camera,
        "steps_per_run": steps,
        "repeats": repeats,
    }
    for name in parts[0]:
        result[f"{name}_us_per_step"] = statistics.median(p[name] for p in parts)
    result["machine"] = {"cpu": platform.processor() or platform.machine(), "core": core, "cores": os.cpu_count()}
    return result
