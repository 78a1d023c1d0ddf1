"""Tests of the per-episode domain randomization of RacerEnv (common.config.RandomizationConfig).

Each randomization must change what it is meant to change, and only when it is enabled: every test
compares against an env with the default configuration (only the random start is on).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import sim  # noqa: F401  (first: picks MuJoCo's GL backend before mujoco is imported)
from common.action_space import MAX_STEERING_DEG
from common.defaults import DEFAULT_TRACK
from sim.camera import CameraSpec, GroundCamera
from sim.env import RacerEnv
from sim.mujoco_camera import RenderError
from sim.physics import WHEEL_RADIUS_M
from sim.texture import DEEPRACER_PALETTE

TRACK = DEFAULT_TRACK
PIN = {"start_index": 3, "reverse": False}
"""Options that pin the start: the same pose in every episode."""
SEEDS = range(5)


def make(**randomization) -> RacerEnv:
    return RacerEnv(track=TRACK, randomization=randomization)


def start_waypoint(env: RacerEnv) -> int:
    """Index of the waypoint (of the track in the episode's direction) the car was placed at."""
    pose = env.physics.pose
    centre = env.task.state.track.center
    dist = np.hypot(centre[:-1, 0] - pose.x, centre[:-1, 1] - pose.y)
    i = int(np.argmin(dist))
    assert dist[i] < 1e-6, "the car does not start on a waypoint"
    return i


def obs_at_pin(env: RacerEnv, seed: int = 0) -> np.ndarray:
    obs, _ = env.reset(seed=seed, options=PIN)
    assert obs.shape == (120, 160, 1) and obs.dtype == np.uint8
    return obs[..., 0].astype(np.float64)


@pytest.fixture(scope="module")
def default_env() -> RacerEnv:
    return make()


@pytest.fixture(scope="module")
def default_obs(default_env: RacerEnv) -> np.ndarray:
    return obs_at_pin(default_env)


# --- start position and direction ---------------------------------------------------------------------


def test_default_config_has_only_random_start_on(default_env: RacerEnv) -> None:
    dr = default_env.config.randomization
    assert dr.random_start
    assert dr.reverse_prob == dr.action_noise == dr.lighting == dr.track_color == dr.texture == 0
    assert dr.camera_jitter_m == dr.camera_jitter_deg == dr.friction == dr.mass == 0


def test_random_start_differs_between_seeds(default_env: RacerEnv) -> None:
    starts = []
    for seed in SEEDS:
        default_env.reset(seed=seed)
        starts.append(start_waypoint(default_env))
    assert len(set(starts)) >= 4, starts
    # The same seed gives the same start.
    default_env.reset(seed=2)
    assert start_waypoint(default_env) == starts[2]


def test_round_robin_start_advances_by_stride() -> None:
    env = make(random_start=False)
    count = env.task.start_indices(False)
    stride = count // env.config.randomization.round_robin_divisions
    assert stride >= 1
    starts = []
    for seed in range(6):
        env.reset(seed=seed)  # a different seed each time: the start must not depend on it
        starts.append(start_waypoint(env))
    assert starts == [(k * stride) % count for k in range(6)]


def test_round_robin_divisions_sets_stride() -> None:
    env = make(random_start=False, round_robin_divisions=4)
    count = env.task.start_indices(False)
    starts = []
    for _ in range(5):
        env.reset(seed=0)
        starts.append(start_waypoint(env))
    assert starts == [(k * (count // 4)) % count for k in range(5)]


def heading_along_forward_track(env: RacerEnv) -> float:
    """cos of the angle between the car's heading and the forward track direction where it stands."""
    pose = env.physics.pose
    track = env.track
    s = float(track.project(np.array([[pose.x, pose.y]])).s[0])
    _, direction = track.point_at(s + 0.01)
    return math.cos(pose.yaw - direction)


def test_reverse_prob_one_reverses_every_episode() -> None:
    env = make(reverse_prob=1.0)
    for seed in SEEDS:
        _, info = env.reset(seed=seed)
        assert info["params"]["is_reversed"] is True
        assert heading_along_forward_track(env) < -0.9


def test_reverse_prob_zero_never_reverses(default_env: RacerEnv) -> None:
    for seed in SEEDS:
        _, info = default_env.reset(seed=seed)
        assert info["params"]["is_reversed"] is False
        assert heading_along_forward_track(default_env) > 0.9


# --- action noise ---------------------------------------------------------------------------------------


def applied_command(env: RacerEnv) -> tuple[np.ndarray, np.ndarray]:
    """(steering deg of both front hinges, speed m/s of all four wheels) from the physics controls."""
    model, ctrl = env.model, env.physics.data.ctrl
    steer = [model.actuator(f"{w}_steer").id for w in ("fl", "fr")]
    drive = [model.actuator(f"{w}_drive").id for w in ("fl", "fr", "rl", "rr")]
    return np.degrees(ctrl[steer]), ctrl[drive] * WHEEL_RADIUS_M


def test_action_noise_perturbs_ctrl_within_bounds() -> None:
    noise = 0.3
    env = make(action_noise=noise)
    env.reset(seed=0)
    steer_diffs, speed_ratios = [], []
    for k in range(30):
        action = k % env.action_space.n
        _, _, terminated, truncated, info = env.step(action)
        command = env.actions.command(action)
        assert info["command"] == command  # info carries the un-noised command
        assert info["params"]["steering_angle"] == command[0]
        assert info["params"]["speed"] == command[1]
        steer, speed = applied_command(env)
        np.testing.assert_allclose(steer, steer[0])
        np.testing.assert_allclose(speed, speed[0])
        expected_lo = max(-MAX_STEERING_DEG, command[0] - noise * MAX_STEERING_DEG)
        expected_hi = min(MAX_STEERING_DEG, command[0] + noise * MAX_STEERING_DEG)
        assert expected_lo - 1e-9 <= steer[0] <= expected_hi + 1e-9
        assert command[1] * (1 - noise) - 1e-9 <= speed[0] <= command[1] * (1 + noise) + 1e-9
        steer_diffs.append(steer[0] - command[0])
        speed_ratios.append(speed[0] / command[1])
        if terminated or truncated:
            env.reset(seed=k + 1)
    # The noise is really there, in both directions, on both commands.
    assert np.sum(np.abs(steer_diffs) > 0.1) >= 20
    assert min(steer_diffs) < 0 < max(steer_diffs)
    assert min(speed_ratios) < 0.97 and max(speed_ratios) > 1.03


def test_no_action_noise_applies_command_exactly(default_env: RacerEnv) -> None:
    default_env.reset(seed=0)
    for action in range(default_env.action_space.n):
        _, _, terminated, truncated, info = default_env.step(action)
        command = default_env.actions.command(action)
        assert info["command"] == command
        steer, speed = applied_command(default_env)
        np.testing.assert_allclose(steer, command[0], atol=1e-9)
        np.testing.assert_allclose(speed, command[1], rtol=1e-12)
        if terminated or truncated:
            default_env.reset(seed=1)


# --- appearance -----------------------------------------------------------------------------------------


def test_lighting_changes_brightness(default_obs: np.ndarray) -> None:
    env = make(lighting=0.5)
    means = [obs_at_pin(env, seed).mean() for seed in SEEDS]
    diffs = [abs(m - default_obs.mean()) for m in means]
    assert max(diffs) > 10, (default_obs.mean(), means)
    assert np.std(means) > 5  # the gain is drawn per episode
    frames = [obs_at_pin(env, seed) for seed in SEEDS]
    assert all(np.abs(f - default_obs).mean() > 1 for f in frames)


def test_no_lighting_gives_identical_frames_at_same_pose(default_env: RacerEnv, default_obs: np.ndarray) -> None:
    for seed in (1, 7, 42):
        np.testing.assert_array_equal(obs_at_pin(default_env, seed), default_obs)
    np.testing.assert_array_equal(obs_at_pin(make(lighting=0.0), 3), default_obs)


def test_track_color_changes_palette_and_observation(default_env: RacerEnv, default_obs: np.ndarray) -> None:
    env = make(track_color=1.0)
    palettes, frames = [], []
    for seed in SEEDS:
        frames.append(obs_at_pin(env, seed))
        palettes.append(env.palette)
    assert len(set(palettes)) == len(palettes)
    assert DEEPRACER_PALETTE not in palettes
    for frame in frames:
        assert np.abs(frame - default_obs).mean() > 5
    # The default env keeps DeepRacer's colours.
    obs_at_pin(default_env, 4)
    assert default_env.palette == DEEPRACER_PALETTE


def road_mask(env: RacerEnv) -> np.ndarray:
    """Texture pixels fully covered by road (no line, no edge)."""
    return env._layers[..., 1] == 255


def test_texture_noise_raises_road_variance(default_env: RacerEnv, default_obs: np.ndarray) -> None:
    road = road_mask(default_env)
    assert road.mean() > 0.05
    flat_var = default_env.texture[road].astype(np.float64).var()
    env = make(texture=0.5)
    for seed in (0, 1):
        frame = obs_at_pin(env, seed)
        noisy_var = env.texture[road].astype(np.float64).var()
        assert noisy_var > 10 * max(flat_var, 1.0), (flat_var, noisy_var)
        assert env.palette == DEEPRACER_PALETTE  # colours untouched without track_color
        assert np.abs(frame - default_obs).mean() > 1


def test_camera_jitter_changes_spec_and_observation(default_env: RacerEnv, default_obs: np.ndarray) -> None:
    assert default_env.camera.spec == CameraSpec()
    env = make(camera_jitter_m=0.02, camera_jitter_deg=3.0)
    specs = []
    for seed in SEEDS:
        frame = obs_at_pin(env, seed)
        spec = env.camera.spec
        specs.append(spec)
        assert spec != CameraSpec()
        nominal = CameraSpec()
        for name in ("forward_m", "left_m", "up_m"):
            assert abs(getattr(spec, name) - getattr(nominal, name)) <= 0.02 + 1e-12
        for name in ("pitch_deg", "yaw_deg", "roll_deg"):
            assert abs(getattr(spec, name) - getattr(nominal, name)) <= 3.0 + 1e-12
        assert np.abs(frame - default_obs).mean() > 1
    assert len(set(specs)) == len(specs)


@pytest.mark.parametrize("randomization", [{"camera_jitter_m": 0.03}, {"camera_jitter_deg": 5.0}])
def test_camera_jitter_either_part_alone(randomization: dict, default_obs: np.ndarray) -> None:
    env = make(**randomization)
    assert np.abs(obs_at_pin(env, 0) - default_obs).mean() > 0.5
    assert env.camera.spec != CameraSpec()


# --- dynamics -------------------------------------------------------------------------------------------


def tyre_ids(env: RacerEnv) -> list[int]:
    return [env.model.geom(f"{w}_tyre").id for w in ("fl", "fr", "rl", "rr")]


def test_friction_and_mass_randomized_within_range(default_env: RacerEnv) -> None:
    nominal_friction = default_env.model.geom_friction[tyre_ids(default_env), 0].copy()
    nominal_mass = default_env.model.body_mass.copy()
    default_env.reset(seed=3)
    np.testing.assert_array_equal(default_env.model.geom_friction[tyre_ids(default_env), 0], nominal_friction)
    np.testing.assert_array_equal(default_env.model.body_mass, nominal_mass)

    f = m = 0.5
    env = make(friction=f, mass=m)
    np.testing.assert_array_equal(env.model.geom_friction[tyre_ids(env), 0], nominal_friction)
    np.testing.assert_array_equal(env.model.body_mass, nominal_mass)
    massive = nominal_mass > 0
    friction_scales, mass_scales = [], []
    for seed in SEEDS:
        env.reset(seed=seed)
        friction = env.model.geom_friction[tyre_ids(env), 0] / nominal_friction
        mass = env.model.body_mass[massive] / nominal_mass[massive]
        np.testing.assert_allclose(friction, friction[0])  # one factor for all tyres
        np.testing.assert_allclose(mass, mass[0])  # and one for all bodies
        assert 1 - f - 1e-9 <= friction[0] <= 1 + f + 1e-9
        assert 1 - m - 1e-9 <= mass[0] <= 1 + m + 1e-9
        friction_scales.append(friction[0])
        mass_scales.append(mass[0])
    assert len(set(np.round(friction_scales, 9))) == len(SEEDS)
    assert len(set(np.round(mass_scales, 9))) == len(SEEDS)
    # The scales apply to the nominal values, not to the last episode's (no drift).
    env.reset(seed=0)
    assert env.model.geom_friction[tyre_ids(env)[0], 0] / nominal_friction[0] == pytest.approx(friction_scales[0])
    assert env.model.body_mass[massive][0] / nominal_mass[massive][0] == pytest.approx(mass_scales[0])


def test_friction_alone_leaves_mass_nominal() -> None:
    env = make(friction=0.5)
    nominal_mass = env.model.body_mass.copy()
    nominal_friction = env.model.geom_friction[tyre_ids(env), 0].copy()
    env.reset(seed=1)
    np.testing.assert_array_equal(env.model.body_mass, nominal_mass)
    assert not np.allclose(env.model.geom_friction[tyre_ids(env), 0], nominal_friction)


# --- augmentations --------------------------------------------------------------------------------------


@pytest.mark.parametrize("prob", ["translate_prob", "shadow_prob", "sharpen_prob", "salt_pepper_prob", "color_prob"])
def test_augmentation_changes_observation(prob: str, default_obs: np.ndarray) -> None:
    env = make(augment={prob: 1.0})
    frames = [obs_at_pin(env, seed) for seed in SEEDS]
    least = 0.05 if prob == "sharpen_prob" else 0.5  # sharpening changes only the edges: a tenth of a level overall
    for frame in frames:
        assert np.abs(frame - default_obs).mean() > least, prob
    # The augmentation is drawn anew each time: the same pose gives different frames.
    assert not any(np.array_equal(frames[0], f) for f in frames[1:])


def test_augmentation_off_by_default(default_env: RacerEnv, default_obs: np.ndarray) -> None:
    aug = default_env.config.randomization.augment
    assert aug.color_prob == aug.translate_prob == aug.shadow_prob == aug.salt_pepper_prob == 0
    np.testing.assert_array_equal(obs_at_pin(default_env, 11), default_obs)


# --- determinism ----------------------------------------------------------------------------------------

EVERYTHING = {
    "reverse_prob": 0.5,
    "action_noise": 0.2,
    "lighting": 0.4,
    "track_color": 0.7,
    "texture": 0.3,
    "camera_jitter_m": 0.01,
    "camera_jitter_deg": 2.0,
    "friction": 0.3,
    "mass": 0.3,
    "augment": {"color_prob": 0.5, "translate_prob": 0.5, "shadow_prob": 0.5, "salt_pepper_prob": 0.5},
}


def rollout(env: RacerEnv, seed: int, actions: list[int]) -> tuple[list[np.ndarray], list[float], list[tuple]]:
    obs, info = env.reset(seed=seed)
    frames, rewards, poses = [obs], [], [info["pose"]]
    for k, action in enumerate(actions):
        obs, reward, terminated, truncated, info = env.step(action)
        frames.append(obs)
        rewards.append(reward)
        poses.append(info["pose"])
        if terminated or truncated:
            obs, info = env.reset(seed=seed + k + 1)
            frames.append(obs)
            poses.append(info["pose"])
    return frames, rewards, poses


def test_determinism_with_everything_on() -> None:
    actions = [int(a) for a in np.random.default_rng(0).integers(0, 10, 30)]
    a = rollout(make(**EVERYTHING), 123, actions)
    b = rollout(make(**EVERYTHING), 123, actions)
    assert len(a[0]) == len(b[0])
    for fa, fb in zip(a[0], b[0], strict=True):
        np.testing.assert_array_equal(fa, fb)
    assert a[1] == b[1]
    assert a[2] == b[2]
    # ... and a different seed gives a different episode.
    c = rollout(make(**EVERYTHING), 124, actions)
    assert not np.array_equal(a[0][0], c[0][0])


def test_randomization_draws_do_not_disturb_start(default_env: RacerEnv) -> None:
    """Appearance randomization is per-episode, yet a pinned start stays pinned."""
    env = make(**EVERYTHING)
    for seed in SEEDS:
        env.reset(seed=seed, options=PIN)
        assert start_waypoint(env) == 3
        assert env.task.state.reversed is False


# --- MuJoCo camera --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "randomization", [{"track_color": 1.0}, {"texture": 0.5}, {"track_color": 0.5, "texture": 0.3}]
)
def test_mujoco_camera_with_surface_randomization(randomization: dict) -> None:
    """camera="mujoco" re-uploads the randomized surface: its frames change and match the fast camera's."""
    try:
        env = RacerEnv(track=TRACK, camera="mujoco", randomization=randomization)
    except RenderError as exc:
        pytest.skip(str(exc))
    try:
        frames = []
        for seed in (0, 1):
            obs, _ = env.reset(seed=seed, options=PIN)
            frames.append(obs[..., 0])
            fast = GroundCamera(env.frame, env.texture, CameraSpec(), env.palette.sky).render(env.physics.pose)
            diff = np.abs(fast.astype(np.int16) - obs[..., 0].astype(np.int16))
            assert diff.mean() < 6, (seed, diff.mean())
        assert np.abs(frames[0].astype(int) - frames[1].astype(int)).mean() > 1
    finally:
        env.close()


def test_stereo_views_get_one_augmentation_draw(tmp_path: Path) -> None:
    """DeepRacer's stereo pair is one sensor: both views get the same noise pixels (one draw, applied to each view
    on its own before the pair is interleaved)."""
    from racer.bench.env import write_sensor_space

    meta = str(write_sensor_space(tmp_path, ["STEREO_CAMERAS"]))
    plain, _ = RacerEnv(track=TRACK, action_space=meta).reset(seed=3, options=PIN)
    noisy_env = RacerEnv(track=TRACK, action_space=meta, randomization={"augment": {"salt_pepper_prob": 1.0}})
    noisy, _ = noisy_env.reset(seed=3, options=PIN)
    assert noisy.shape == plain.shape == (120, 160, 2) and noisy.dtype == np.uint8
    assert (plain[..., 0] != plain[..., 1]).any()  # two cameras 6 cm apart
    hit = (noisy != plain).any(axis=2)
    assert hit.sum() > 100
    np.testing.assert_array_equal(noisy[hit, 0], noisy[hit, 1])  # the same pixels, set to the same values
    assert set(np.unique(noisy[hit])) <= {0, 255}
