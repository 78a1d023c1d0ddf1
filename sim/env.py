"""The gymnasium adapter: ``gymnasium.make("sim:Racer-v0", track="racer_loop", ...)``.

Thin by design: the car (``physics``), the world and camera (``world``, ``camera``, ``texture``),
the task (``task``) and the user's reward function (``reward``) do the work; this module wires
them together, applies the per-episode domain randomization and keeps ``terminated`` (off track,
lap complete, immobilized, reversed) apart from ``truncated`` (time limit).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import numpy as np

from common.action_space import (
    MAX_STEERING_DEG,
    ActionSpace,
    clip_command,
    default_action_space,
    load_action_space,
)
from common.config import FRAME_HEIGHT, FRAME_WIDTH, EnvConfig, WorldCondition
from common.defaults import DEFAULT_TRACK
from common.errors import UserError
from common.privileged import STATE_SIZE, state_vector
from common.sensors import CAMERA_KEY, LIDAR_KEY, ObsSpec, lidar_from_ranges, observation_spec
from common.simtrace import OBSTACLE_COLUMN
from sim.augment import augment_frame, is_identity, needs_color
from sim.camera import CameraSpec, GroundCamera, StereoGroundCamera
from sim.conditions import FrameCondition
from sim.lidar import Lidar, scan_due
from sim.mujoco_camera import MujocoCamera
from sim.obstacles import WorldObject, as_boxes
from sim.physics import CarPhysics, Pose
from sim.race_rules import RaceObjects, reset_pose, start_pose
from sim.reward import RewardFunction, RewardFunctionError, example_path, load_reward_function
from sim.task import RacingTask, Status, StepResult
from sim.texture import (
    DEEPRACER_PALETTE,
    Palette,
    RoadMask,
    TextureFrame,
    add_noise_texture,
    colorize,
    draw_layers,
    random_palette,
)
from sim.track import Track, load_track
from sim.views import top_down
from sim.world import CONTROL_HZ, build_model, object_slot_geoms, set_objects

OBS_SHAPE = (FRAME_HEIGHT, FRAME_WIDTH, 1)


class RacerEnv(gym.Env):
    """A DeepRacer car on a DeepRacer track, seen through its 160×120 grayscale camera at 15 Hz.

    Keyword arguments are the fields of :class:`common.config.EnvConfig` (or pass ``config=``).
    ``reset(options=...)`` accepts ``start_index`` (waypoint) and ``reverse`` (bool) to pin the start.
    ``info`` carries ``params`` (DeepRacer's reward-function input), ``reward_terms``,
    ``episode_status``, ``progress``, ``steps`` (env steps in this episode; ``params["steps"]`` is one more, as
    DeepRacer counts its prepare step) and ``command`` (the steering/speed actually applied).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": CONTROL_HZ}

    def __init__(self, config: EnvConfig | None = None, render_mode: str | None = None, **kwargs: Any) -> None:
        self.config = config or EnvConfig(**kwargs)
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r} is not supported; use 'rgb_array'")
        self.render_mode = render_mode
        cfg = self.config
        self.track: Track = load_track(cfg.track)
        self.actions: ActionSpace = load_action_space(cfg.action_space) if cfg.action_space else default_action_space()
        self.reward_fn: RewardFunction = load_reward_function(
            cfg.reward_fn or example_path("default"), time_limit_s=cfg.reward_time_limit_s
        )
        self.obs_spec: ObsSpec = observation_spec(self.actions.sensor, 1)
        self.race = RaceObjects(self.track, cfg.race)
        self.objects: list[WorldObject] = []
        self._box_colors: np.ndarray | None = None
        self._resets_left, self._pause_s = 0, 0.0
        self._build_world()
        self.task = RacingTask(self.track, road=RoadMask(self.track, self.frame))
        self.observation_space = self._observation_space()
        self.action_space = self._gym_action_space()
        self._episodes = 0
        self._gain: np.ndarray | None = None
        self._last: StepResult | None = None

    # --- construction -------------------------------------------------------------------------
    def _build_world(self) -> None:
        cfg = self.config
        self.frame = TextureFrame.for_track(self.track, cfg.texture_ppm)
        self._layers = draw_layers(self.track, self.frame)
        self.palette: Palette = _conditioned(DEEPRACER_PALETTE, cfg.condition)
        self.texture = colorize(self._layers, self.palette)
        mujoco_cam = cfg.camera == "mujoco"
        slots = self.race.slots
        self.model = build_model(self.frame, self.texture if mujoco_cam else None, self.palette.sky, object_slots=slots)
        self.physics = CarPhysics(self.model)
        self.physics.set_calibration(cfg.car)
        self.camera_spec = CameraSpec(pitch_deg=CameraSpec().pitch_deg + cfg.condition.camera_pitch_deg)
        self._frame_condition = FrameCondition(cfg.condition, OBS_SHAPE[:2])
        stereo = self.obs_spec.frame_channels == 2
        if mujoco_cam and stereo:
            raise UserError("camera 'mujoco' renders one camera, not STEREO_CAMERAS: use camera 'ground'")
        if mujoco_cam:
            self.camera: GroundCamera | MujocoCamera | StereoGroundCamera = MujocoCamera(
                self.model, self.physics.data, self.camera_spec
            )
        elif stereo:
            self.camera = StereoGroundCamera(self.frame, self.texture, self.camera_spec, self.palette.sky)
        else:
            self.camera = GroundCamera(self.frame, self.texture, self.camera_spec, self.palette.sky)
        self.lidar = Lidar(self.model, self.physics.data) if self.obs_spec.lidar else None
        self._lidar_obs: np.ndarray | None = None
        """The last scan's observation: DeepRacer's 10 Hz LiDAR is repeated on steps with no new scan."""
        # The MuJoCo scene holds the objects only where something looks at it: the LiDAR's rays, MuJoCo's camera.
        self._slot_geoms = object_slot_geoms(self.model) if slots and (self.lidar or mujoco_cam) else None

    def _observation_space(self) -> gym.spaces.Space:
        if self.config.observation == "state":
            return gym.spaces.Box(-np.inf, np.inf, (STATE_SIZE,), np.float32)
        camera = gym.spaces.Box(0, 255, self.obs_spec.frame_shape((FRAME_HEIGHT, FRAME_WIDTH)), np.uint8)
        lidar = self.obs_spec.lidar
        if lidar is None:
            return camera
        return gym.spaces.Dict(
            {CAMERA_KEY: camera, LIDAR_KEY: gym.spaces.Box(lidar.low, lidar.high, (lidar.size,), np.float32)}
        )

    def _gym_action_space(self) -> gym.spaces.Space:
        if self.actions.discrete:
            return gym.spaces.Discrete(self.actions.n)
        rng = self.actions.action_space
        low = np.array([rng.steering_angle.low, rng.speed.low], np.float32)
        high = np.array([rng.steering_angle.high, rng.speed.high], np.float32)
        return gym.spaces.Box(low, high, dtype=np.float32)

    # --- gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Start an episode: randomize as configured, place the car at rest at a start waypoint."""
        super().reset(seed=seed)
        options = options or {}
        dr, rng = self.config.randomization, self.np_random
        drawn = self._episodes % 2 == 1 if dr.alternate_direction else rng.random() < dr.reverse_prob
        reverse = bool(options.get("reverse", drawn))
        index = self._start_index(reverse, options.get("start_index"))
        self._randomize(rng)
        self.objects = self.race.reset(rng, reverse)
        # DeepRacer's evaluation puts the car back after an off-track or a crash, with a penalty, up to
        # NUMBER_OF_RESETS times; training ends the episode (markov/rollout_worker.py passes 0 resets).
        self._resets_left = self.config.race.penalties.number_of_resets if options.get("evaluation") else 0
        self._pause_s = 0.0
        pose = self.task.start_pose(index, reverse)
        if self.objects and options.get("start_index") is None:
            # A training start within 1 m of an object moves to the other lane (simapp RolloutCtrl.
            # _get_car_start_model_state); an evaluation (a pinned start) starts on the centre line regardless.
            pose = start_pose(self.track, reverse, self.task.start_distance(index, reverse), self.objects)
        self.physics.reset(pose)
        self.place_objects()
        self.task.begin(index, reverse)
        self._command = (0.0, 0.0)
        wheels = self.physics.wheel_positions()
        self._last = self.task.observe(pose, wheels, True, 0.0, self._command, count_step=False, objects=self.objects)
        self._episodes += 1
        return self.observe(), self._info(self._last, 0.0)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Apply one action for 1/15 s and return (obs, reward, terminated, truncated, info)."""
        if self._last is None:
            raise RuntimeError("call reset() before step()")
        # The reward function is told the action's own values; the car gets them within its limits.
        requested = self.actions.values(action)
        command = clip_command(*requested)
        self._command = command
        steer, speed = self._noisy(command)
        cap = self.config.condition.speed_cap_mps
        self.physics.command(steer, speed if cap is None else min(speed, cap))
        self.physics.step()
        ph = self.physics
        crashed = self.move_objects()
        sim_time = ph.time + self._pause_s
        result = self.task.observe(
            ph.pose, ph.wheel_positions(), ph.upright, sim_time, requested, objects=self.objects, crashed=crashed
        )
        reward = self.reward_fn(result.params, step=result.params["steps"])
        pause = self._penalty_reset(result) if result.terminated else 0.0
        terminated = result.terminated and not pause
        truncated = not terminated and self.task.steps >= self.config.time_limit_steps
        status = Status.TIME_UP if truncated else result.status
        self._last = result
        info = self._info(result, reward, status)
        if pause:
            info["pause_duration"] = pause
        return self.observe(), reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """Top-down RGB view of the track with the car (``render_mode="rgb_array"``)."""
        if self.render_mode != "rgb_array":
            return None
        return top_down(self.track, self.texture, self.frame, [self.physics.pose], objects=self.objects)

    def close(self) -> None:
        """Release the renderer, if any."""
        if isinstance(self.camera, MujocoCamera):
            self.camera.close()

    # --- helpers ------------------------------------------------------------------------------
    def _start_index(self, reverse: bool, pinned: int | None) -> int:
        count = self.task.start_indices(reverse)
        if pinned is not None:
            return int(pinned) % count
        dr = self.config.randomization
        if dr.random_start:
            return int(self.np_random.integers(count))
        stride = max(1, count // dr.round_robin_divisions)
        return (self._episodes * stride) % count

    def _noisy(self, command: tuple[float, float]) -> tuple[float, float]:
        """Uniform action noise: steering ± noise × 30°, speed × (1 ± noise)."""
        noise = self.config.randomization.action_noise
        if noise <= 0:
            return command
        d_steer, d_speed = self.np_random.uniform(-noise, noise, 2)
        return clip_command(command[0] + d_steer * MAX_STEERING_DEG, command[1] * (1 + d_speed))

    def _randomize(self, rng: np.random.Generator) -> None:
        dr = self.config.randomization
        if dr.friction or dr.mass:
            self.physics.set_dynamics(
                1 + rng.uniform(-dr.friction, dr.friction) if dr.friction else 1.0,
                1 + rng.uniform(-dr.mass, dr.mass) if dr.mass else 1.0,
            )
        if dr.camera_jitter_m or dr.camera_jitter_deg:
            self.camera.set_spec(self.camera_spec.jittered(rng, dr.camera_jitter_m, dr.camera_jitter_deg))
        if dr.track_color or dr.texture:
            palette = random_palette(rng, dr.track_color) if dr.track_color else DEEPRACER_PALETTE
            self.palette = _conditioned(palette, self.config.condition)  # a condition's colours are fixed
            texture = colorize(self._layers, self.palette)
            if dr.texture:
                texture = add_noise_texture(texture, dr.texture, rng)
            self.texture = texture
            self.camera.set_surface(texture, self.palette.sky)
        if dr.track_color and self.race.slots:
            # Obstacles and bots change colour with the track (DeepRacer's default box is brown, its bots grey):
            # a policy must not learn to avoid one colour.
            self._box_colors = rng.integers(30, 226, (self.race.slots, 3)).astype(np.uint8)
        self._gain = _lighting_gain(rng, dr.lighting) if dr.lighting else None
        self._frame_condition.begin(rng)

    def _penalty_reset(self, result: StepResult) -> float:
        """An evaluation reset (simapp ``RolloutCtrl._judge_action_at_run_phase`` and
        ``_get_car_reset_model_state``): after an off-track, crash, reversal or immobilization with resets left, the
        car is put back on the track (behind a nearby obstacle, in the other lane; after a crash into a bot, where it
        is) and the clock runs on by the penalty, which lands in the lap time; the bots drive on through the pause
        (``RaceObjects.pause``). Returns the penalty in seconds; 0 when the episode ends instead."""
        penalties = self.config.race.penalties
        by_status = {
            Status.OFF_TRACK: penalties.off_track_penalty,
            Status.CRASHED: penalties.collision_penalty,
            Status.REVERSED: penalties.reverse_penalty_s,
            Status.IMMOBILIZED: penalties.immobilized_penalty,
        }
        if self._resets_left <= 0 or result.status not in by_status:
            return 0.0
        self._resets_left -= 1
        crashed = result.status == Status.CRASHED
        if crashed and self.race.crashed_into is not None and not self.race.crashed_into.is_obstacle:
            # A crash into a bot: the simapp pauses the car where it is (only an obstacle's name moves it).
            pose = self.physics.pose
        else:
            # After a crash the car is put back where it is; otherwise where it was a step ago, still on the track.
            at = result if crashed else self._last
            pose = reset_pose(
                self.track,
                self.task.state.reversed,
                float(at.params["projection_distance"]),
                Pose(*(at.params[k] for k in ("x", "y")), 0.0),
                self.objects,
                behind_m=penalties.reset_behind_dist,
            )
        self.physics.reset(pose)
        penalty = by_status[result.status]
        self.objects = self.race.pause(penalty)
        self.place_objects()
        self.task.relocate(pose)
        self._pause_s += penalty
        return max(penalty, 1e-9)  # a 0 s penalty still resets

    # --- the parts of a step, public so that a bench or a test can run (and time) each alone ----------------
    def move_objects(self) -> bool:
        """The race's objects one step on, placed in the scene; True if the car now touches one."""
        self.objects = self.race.step()
        self.place_objects()
        pose, progress = self.physics.pose, self._last.params["progress"]
        return bool(self.objects) and self.race.crashed(pose, progress, self.task.start_fraction)

    def place_objects(self) -> None:
        """Move the MuJoCo scene's object slots to this step's objects (after every physics reset too: it
        puts the slots back where they were compiled)."""
        if self._slot_geoms is not None:
            set_objects(self.model, self.physics.data, as_boxes(self.objects), slots=self._slot_geoms)

    def observe(self) -> np.ndarray | dict[str, np.ndarray]:
        """The observation at the car's pose now: the camera frame, and the LiDAR vector where the sensors have one
        (scanned again when due, else the last scan); with ``observation`` ``state``, the car's privileged state
        instead, and nothing is rendered."""
        if self.config.observation == "state":
            return state_vector(self._last.params)
        pose = self.physics.pose
        frame = self.camera_frame(pose)
        if self.lidar is None:
            return frame
        if self._lidar_obs is None or scan_due(self.task.steps):
            ranges = self.lidar.scan(pose, self.np_random)
            self._lidar_obs = lidar_from_ranges(self.obs_spec.lidar.name, ranges)
        return {CAMERA_KEY: frame, LIDAR_KEY: self._lidar_obs.copy()}

    def camera_frame(self, pose: Pose) -> np.ndarray:
        """(H, W, 1) or, stereo, (H, W, 2) uint8: the render with this step's objects, the episode's lighting and
        the frame augmentations (the same draw for both views of a stereo pair)."""
        aug = self.config.randomization.augment
        boxes = as_boxes(self.objects) if self.objects else None
        if isinstance(self.camera, StereoGroundCamera):
            # Each view is lit and augmented on its own, contiguous, and the pair interleaved once at the end.
            views = self.camera.render_views(pose, boxes=boxes, box_colors=self._box_colors)
            seed = int(self.np_random.integers(2**63))
            if self._gain is not None:
                views = tuple(cv2.convertScaleAbs(v.astype(np.float32) * self._gain) for v in views)
            if not is_identity(aug):
                views = tuple(augment_frame(v, aug, np.random.default_rng(seed)) for v in views)
            pair = cv2.merge(views)
            return self._frame_condition.apply(pair, self.np_random) if self._frame_condition.active else pair
        frame = self.camera.render(pose, color=needs_color(aug), boxes=boxes, box_colors=self._box_colors)
        if self._gain is not None:
            gain = self._gain[..., None] if frame.ndim == 3 else self._gain
            frame = cv2.convertScaleAbs(frame.astype(np.float32) * gain)
        if not (frame.ndim == 2 and is_identity(aug)):
            frame = augment_frame(frame, aug, self.np_random)
        if self._frame_condition.active:
            frame = self._frame_condition.apply(frame, self.np_random)
        return frame[..., None]  # a fresh array each step: nothing to copy

    def _info(self, result: StepResult, reward: float, status: str | None = None) -> dict:
        extra = {OBSTACLE_COLUMN: self.race.crash_count} if self.race.slots else {}
        return extra | {
            "params": result.params,
            "reward_terms": {"reward_function": reward},
            "episode_status": status or result.status,
            "progress": result.params["progress"],
            "steps": self.task.steps,
            "command": self._command,
            "pose": self.physics.pose,
        }


def _conditioned(palette: Palette, condition: WorldCondition) -> Palette:
    """``palette`` with the colours a held-out condition fixes."""
    fixed = {k: getattr(condition, k) for k in ("road", "border", "center", "background", "sky")}
    return dataclasses.replace(palette, **{k: tuple(v) for k, v in fixed.items() if v is not None})


def _lighting_gain(rng: np.random.Generator, strength: float) -> np.ndarray:
    """Per-episode light: overall brightness × (1 ± strength) and a linear gradient in a random direction."""
    h, w = OBS_SHAPE[:2]
    angle = rng.uniform(0, 2 * np.pi)
    yy, xx = np.mgrid[-1 : 1 : h * 1j, -1 : 1 : w * 1j]
    ramp = (np.cos(angle) * xx + np.sin(angle) * yy) / np.sqrt(2)
    gain = (1 + rng.uniform(-strength, strength)) * (1 + 0.5 * strength * ramp)
    return gain.astype(np.float32)


PREFLIGHT_STEPS = 15
"""Steps (1 s at 15 Hz) that the pre-start check drives in each direction."""


def preflight_reward(config: EnvConfig, steps: int = PREFLIGHT_STEPS) -> None:
    """Call the run's reward function as training will, before training: raise RewardFunctionError if it fails.

    A throwaway env on the run's own track and action space loads its own copy of the reward module, so
    whatever the function caches on its first calls (a racing line, a class instance) is never seen by
    training. It drives straight at the slowest speed from the first start waypoint for ``steps`` steps,
    in both directions when the run drives both, so the function gets the params of a real episode.
    """
    # What the function prints (many community functions print every call, some at import) belongs in the
    # workers' logs, as in DeepRacer's, not between the lines racer train and racer check print.
    with contextlib.redirect_stdout(io.StringIO()):
        _drive_preflight(config, steps)


def _drive_preflight(config: EnvConfig, steps: int) -> None:
    env = RacerEnv(config=config.model_copy(update={"camera": "ground"}))
    try:
        directions = (False, True) if _drives_reversed(config) else (False,)
        for reverse in directions:
            env.reset(seed=0, options={"start_index": 0, "reverse": reverse})
            action = _gentlest_action(env.actions)
            for _ in range(steps):
                try:
                    _, _, terminated, truncated, _ = env.step(action)
                except RewardFunctionError as exc:
                    raise RewardFunctionError(f"{exc} (checked before training)") from exc
                if terminated or truncated:
                    break
    finally:
        env.close()


def _drives_reversed(config: EnvConfig) -> bool:
    dr = config.randomization
    return dr.reverse_prob > 0 or dr.alternate_direction


def _gentlest_action(actions: ActionSpace) -> Any:
    """The discrete action closest to straight at the lowest speed, or the continuous space's equivalent."""
    if actions.discrete:
        listed = actions.action_space
        return min(range(actions.n), key=lambda i: (abs(listed[i].steering_angle), listed[i].speed))
    rng = actions.action_space
    steer = min(max(0.0, rng.steering_angle.low), rng.steering_angle.high)
    return np.array([steer, rng.speed.low], np.float32)


def make_env(track: str | Path = DEFAULT_TRACK, **kwargs: Any) -> RacerEnv:
    """Build an env directly (same as ``gymnasium.make("sim:Racer-v0", ...)`` without wrappers)."""
    return RacerEnv(track=str(track), **kwargs)
