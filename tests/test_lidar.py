"""Tests of DeepRacer's LIDAR and SECTOR_LIDAR (sim.lidar) and of the scene's object slots (sim.world).

The values are deepracer-simapp's (aws-deepracer-community/deepracer-simapp, under ``bundle/``):
``markov/sensors/constants.py`` and ``src/deepracer_simulation_environment/launch/racecar.launch.py`` (scan),
``urdf/deepracer/deepracer_*_lidar.urdf`` (mount), ``markov/sagemaker_graph_manager.py`` (the LIDAR clipping
filter and the SECTOR_LIDAR filter's arguments), ``markov/environments/constants.py`` (sectors, clipping distance),
``markov/filters/observation/observation_sector_discretize_filter.py`` (the sector filter).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from common.sensors import SECTOR_LIDAR, lidar_from_ranges
from sim.lidar import (
    LIDAR_MAX_RANGE,
    LIDAR_MIN_RANGE,
    Lidar,
    LidarSpec,
    analytic_ranges,
    analytic_scan,
)
from sim.physics import CarPhysics, Pose
from sim.texture import TextureFrame
from sim.world import (
    HIDDEN_GEOM_GROUP,
    OBJECT_GEOM_GROUP,
    build_model,
    object_slot_geoms,
    set_objects,
)

FRAME = TextureFrame(x0=-5.0, y1=5.0, ppm=50.0, width=500, height=500)
SLOTS = 8
OBSTACLE = (0.4, 0.3, 0.25)  # DeepRacer's box_obstacle, bundle/models/box_obstacle/model.sdf


@pytest.fixture(scope="module")
def world() -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = build_model(FRAME, object_slots=SLOTS)
    physics = CarPhysics(model)
    physics.reset(Pose(0.0, 0.0, 0.0))
    return model, physics.data


def sector_observation(lidar: Lidar, pose: Pose, rng: np.random.Generator | None = None) -> np.ndarray:
    """The SECTOR_LIDAR observation as the env makes it: the scan through the sector filter."""
    return lidar_from_ranges(SECTOR_LIDAR, lidar.scan(pose, rng))


def get_objects(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """The (K, 6) boxes of the slots in use, as :func:`set_objects` took them (from the current kinematics)."""
    geoms = object_slot_geoms(model)
    geoms = geoms[model.geom_group[geoms] == OBJECT_GEOM_GROUP]
    pos = data.geom_xpos[geoms]
    mat = data.geom_xmat[geoms]
    yaw = np.arctan2(mat[:, 3], mat[:, 0])
    size = 2 * model.geom_size[geoms]
    return np.column_stack([pos[:, 0], pos[:, 1], yaw, size])


def box_at(pose: Pose, distance: float, bearing_deg: float, size=OBSTACLE, yaw: float = 0.0) -> list[float]:
    """A box whose centre is ``distance`` from the lidar at ``bearing_deg`` (car frame, anticlockwise from ahead),
    its length along that bearing turned by ``yaw``."""
    spec = LidarSpec()
    sx = pose.x + spec.forward_m * math.cos(pose.yaw)
    sy = pose.y + spec.forward_m * math.sin(pose.yaw)
    a = pose.yaw + math.radians(bearing_deg)
    return [sx + distance * math.cos(a), sy + distance * math.sin(a), a + yaw, *size]


def random_boxes(rng: np.random.Generator, k: int) -> np.ndarray:
    return np.column_stack(
        [
            rng.uniform(-2.5, 2.5, (k, 2)),
            rng.uniform(-math.pi, math.pi, k),
            rng.uniform(0.05, 1.2, (k, 2)),
            rng.uniform(0.1, 0.5, k),  # some lower than the sensor (0.185 m): not seen
        ]
    )


# --- DeepRacer's values ---------------------------------------------------------------------------------


def test_spec_is_deepracers() -> None:
    spec = LidarSpec()
    # markov/sensors/constants.py, racecar.launch.py
    assert spec.samples == 64
    assert (spec.min_angle, spec.max_angle) == (-2.61799, 2.61799)
    assert (spec.min_range, spec.max_range) == (0.15, 12.0)
    assert spec.noise_stddev == 0.01
    # deepracer_stereo_cam_lidar.urdf: base_link_joint z 0.023249, hokuyo_joint xyz (0.02913, 0, 0.16145) yaw 3.1416
    assert spec.height_m == pytest.approx(0.023249 + 0.16145)
    assert (spec.forward_m, spec.left_m, spec.yaw) == (0.02913, 0.0, 3.1416)


def test_scan_sweeps_anticlockwise_from_front_left_with_the_blind_cone_ahead() -> None:
    angles = np.degrees(LidarSpec().angles())
    assert angles.shape == (64,)
    assert angles[0] == pytest.approx(30.0, abs=0.01)  # 180° - 150°
    assert angles[-1] == pytest.approx(330.0, abs=0.01)  # i.e. 30° right of ahead
    assert np.all(np.diff(angles) > 0)
    assert np.diff(angles) == pytest.approx(300.0 / 63, abs=1e-4)


# --- the MuJoCo cast against the closed form ------------------------------------------------------------


def test_mujoco_cast_matches_analytic_on_random_layouts(world) -> None:
    model, data = world
    lidar = Lidar(model, data)
    rng = np.random.default_rng(7)
    hits = 0
    for _ in range(150):
        boxes = random_boxes(rng, int(rng.integers(1, SLOTS + 1)))
        set_objects(model, data, boxes)
        pose = Pose(*rng.uniform(-1.5, 1.5, 2), rng.uniform(-math.pi, math.pi))
        s = LidarSpec()
        origin = np.array([pose.x + s.forward_m * math.cos(pose.yaw), pose.y + s.forward_m * math.sin(pose.yaw)])
        expected = analytic_ranges(origin, s.angles() + pose.yaw, boxes, s.height_m, s.max_range)
        lidar.scan(pose)
        measured = lidar._dist  # the raw cast: -1 where nothing is hit
        np.testing.assert_array_equal(measured < 0, expected < 0)
        np.testing.assert_allclose(measured[expected >= 0], expected[expected >= 0], atol=1e-3)
        np.testing.assert_allclose(lidar.scan(pose), analytic_scan(pose, boxes), atol=1e-3)
        hits += int((expected >= 0).sum())
    assert hits > 1000  # the layouts put boxes in the way


def test_analytic_ray_box() -> None:
    box = np.array([[2.0, 0.0, 0.0, 1.0, 0.5, 1.0]])
    angles = np.array([0.0, math.pi, math.atan2(0.25, 1.5), math.atan2(0.3, 1.5)])
    d = analytic_ranges(np.zeros(2), angles, box, height=0.2)
    assert d[0] == pytest.approx(1.5)
    assert d[1] == -1.0
    assert d[2] == pytest.approx(math.hypot(1.5, 0.25))  # through the corner
    assert d[3] == -1.0
    # Turned 90°: the near face is 0.25 m from the centre.
    assert analytic_ranges(np.zeros(2), np.zeros(1), box + [0, 0, math.pi / 2, 0, 0, 0], 0.2)[0] == pytest.approx(1.75)
    # Lower than the sensor: not seen; beyond max range: not seen.
    assert analytic_ranges(np.zeros(2), np.zeros(1), box, height=1.0)[0] == -1.0
    assert analytic_ranges(np.zeros(2), np.zeros(1), box, height=0.2, max_range=1.0)[0] == -1.0


def test_car_and_ground_are_never_hit(world) -> None:
    model, data = world
    set_objects(model, data, np.zeros((0, 6)))
    # The car stands at the origin; its own geoms surround the sensor and the ground plane is right below it.
    scan = Lidar(model, data).scan(Pose(0.0, 0.0, 0.0))
    np.testing.assert_array_equal(scan, np.float32(np.inf))  # gz: a miss is +inf (REP 117), not the max range


# --- observations ---------------------------------------------------------------------------------------


def test_lidar_observation_shape_range_and_clipping(world) -> None:
    model, data = world
    pose = Pose(0.3, -0.2, 0.7)
    set_objects(model, data, np.array([box_at(pose, 0.5, 180.0), box_at(pose, 3.0, 90.0)]))
    lidar = Lidar(model, data)
    obs = lidar.observe(pose, np.random.default_rng(0))
    assert obs.shape == (64,) and obs.dtype == np.float32
    assert obs.min() >= 0.15 and obs.max() <= 1.0
    clean = lidar.observe(pose)
    # Straight behind (samples 31 and 32, 1.5° either side) the box's face is 0.3 m away.
    assert clean[31] == pytest.approx(0.3 / math.cos(math.radians(300 / 63 / 2)), abs=1e-4)
    assert clean[32] == pytest.approx(clean[31], abs=1e-4)
    # The box 3 m to the left reads 1.0 (clipped), as does nothing at all.
    assert clean[13] == 1.0
    assert 8 <= np.sum(clean < 1.0) <= 13  # the near box spans about ±27°
    scan = lidar.scan(pose)
    assert scan.dtype == np.float32 and scan.max() == np.inf and scan[np.isfinite(scan)].max() < LIDAR_MAX_RANGE
    # The raw scan keeps the distance: sample 13 looks 1.9° behind the left, at the face 2.8 m away.
    assert scan[13] == pytest.approx(2.8 / math.cos(math.radians(30 + 13 * 300 / 63 - 90)), abs=1e-3)


def test_blind_cone_ahead_and_min_range(world) -> None:
    model, data = world
    pose = Pose(0.0, 0.0, 0.0)
    lidar = Lidar(model, data)
    set_objects(model, data, np.array([box_at(pose, 0.5, 0.0)]))  # straight ahead: in the blind 60°
    np.testing.assert_array_equal(lidar.observe(pose), np.float32(1.0))
    set_objects(model, data, np.array([box_at(pose, 0.5, 35.0)]))  # just inside the scan on the left
    assert lidar.observe(pose)[0] < 1.0
    # A face nearer than the 0.15 m minimum range reads -inf (gz-rendering's gpu_rays_1st_pass_fs.glsl: l < near
    # → min, -inf unclamped), which the LIDAR filter clips to 0.15 and the SECTOR_LIDAR filter takes for nothing.
    set_objects(model, data, np.array([box_at(pose, 0.3, 180.0, size=(0.4, 0.4, 0.3))]))
    scan = lidar.scan(pose)
    assert scan[31] == -np.inf and np.all(np.isneginf(lidar.scan(pose, np.random.default_rng(0))[31:33]))
    assert lidar.observe(pose)[31] == np.float32(LIDAR_MIN_RANGE)
    assert sector_observation(lidar, pose)[3:5].tolist() == [0.0, 0.0]
    # Inside the cube map's near clip (0.15 / sqrt(3) m along the face's axis) nothing is drawn: no hit.
    set_objects(model, data, np.array([box_at(pose, 0.28, 180.0, size=(0.4, 0.4, 0.3))]))
    assert lidar.scan(pose)[31] == np.inf
    # ...but a face just beyond it is, and noise cannot take it below 0.15.
    set_objects(model, data, np.array([box_at(pose, 0.36, 180.0, size=(0.4, 0.4, 0.3))]))
    rng = np.random.default_rng(1)
    scans = np.array([lidar.scan(pose, rng)[31] for _ in range(200)])
    assert scans.min() >= np.float32(LIDAR_MIN_RANGE) and np.mean(scans == np.float32(0.15)) > 0.05


def test_noise_is_gaussian_one_centimetre_and_seeded(world) -> None:
    model, data = world
    pose = Pose(0.0, 0.0, 0.0)
    set_objects(model, data, np.array([box_at(pose, 0.7, 180.0, size=(0.4, 2.0, 0.3))]))
    lidar = Lidar(model, data)
    clean = lidar.scan(pose)
    noisy = np.array([lidar.scan(pose, np.random.default_rng(s)) for s in range(300)])
    err = noisy[:, 28:36] - clean[28:36]  # rays on the box face, far from any clamp
    assert abs(err.mean()) < 0.002 and err.std() == pytest.approx(0.01, rel=0.1)
    np.testing.assert_array_equal(lidar.scan(pose, np.random.default_rng(3)), noisy[3])
    assert np.all(noisy[:, 0] == np.inf)  # misses: +inf + noise stays +inf (gz-sensors clamps finite ranges only)


def test_ranges_are_not_quantized_to_the_range_resolution(world) -> None:
    # The urdf's <range><resolution>0.01 is never applied: gz-sensors 8 only returns it (Lidar::RangeResolution),
    # and neither the gpu_rays shaders, Lidar::ApplyNoise, PublishLidarScan nor the ROS bridge round a range.
    model, data = world
    pose = Pose(0.0, 0.0, 0.0)
    set_objects(model, data, np.array([box_at(pose, 0.7034, 180.0, size=(0.4, 2.0, 0.3))]))
    clean = Lidar(model, data).scan(pose)
    expected = 0.5034 / math.cos(math.radians(300 / 63 / 2))
    assert clean[31] == pytest.approx(expected, abs=1e-4)
    assert abs(clean[31] * 100 - round(clean[31] * 100)) > 0.1  # 0.50384: between two centimetres


def test_sector_lidar_sees_a_box_within_half_a_metre(world) -> None:
    model, data = world
    pose = Pose(0.5, 0.5, 2.0)
    lidar = Lidar(model, data)
    set_objects(model, data, np.array([box_at(pose, 0.6, 180.0)]))  # face at 0.4 m behind: sectors 3 and 4
    obs = sector_observation(lidar, pose, np.random.default_rng(0))
    assert obs.shape == (8,) and obs.dtype == np.float32
    np.testing.assert_array_equal(obs, [0, 0, 0, 1, 1, 0, 0, 0])
    set_objects(model, data, np.array([box_at(pose, 0.9, 180.0)]))  # face at 0.7 m: none
    np.testing.assert_array_equal(sector_observation(lidar, pose), np.zeros(8))
    # To the left (sector k spans 30° + 37.5° k to 30° + 37.5° (k + 1)), face at 0.25 m, ±31° wide.
    set_objects(model, data, np.array([box_at(pose, 0.45, 90.0)]))
    np.testing.assert_array_equal(sector_observation(lidar, pose), [1, 1, 1, 0, 0, 0, 0, 0])


# --- object slots in the world --------------------------------------------------------------------------


def test_no_slots_compiles_todays_scene() -> None:
    plain, slotted = build_model(FRAME), build_model(FRAME, object_slots=0)
    assert (plain.nbody, plain.ngeom, plain.nmocap) == (slotted.nbody, slotted.ngeom, slotted.nmocap)
    for name in ("geom_size", "geom_pos", "body_mass", "body_inertia", "geom_friction", "actuator_gainprm"):
        np.testing.assert_array_equal(getattr(plain, name), getattr(slotted, name))
    assert len(object_slot_geoms(plain)) == 0
    set_objects(plain, mujoco.MjData(plain), np.zeros((0, 6)))  # nothing to do
    with pytest.raises(ValueError, match="object slots"):
        set_objects(plain, mujoco.MjData(plain), np.array([[0, 0, 0, 1, 1, 1]]))


def test_slots_do_not_change_the_car_physics() -> None:
    plain, slotted = build_model(FRAME), build_model(FRAME, object_slots=4)
    assert slotted.stat.extent == plain.stat.extent and slotted.stat.meaninertia == plain.stat.meaninertia
    runs = []
    for model in (plain, slotted):
        physics = CarPhysics(model)
        physics.reset(Pose(0.0, 0.0, 0.0))
        if model is slotted:  # boxes on the car's path and on top of it: no contacts
            set_objects(
                model, physics.data, np.array([[0.5, 0.0, 0.3, 0.4, 0.3, 0.25], [0.0, 0.0, 0.0, 0.4, 0.4, 0.3]])
            )
        for k in range(45):
            physics.command(20.0 if k < 20 else -10.0, 2.0)
            physics.step()
        runs.append(physics.data.qpos[:7].copy())
    np.testing.assert_array_equal(runs[0], runs[1])


def test_set_objects_places_sizes_and_hides(world) -> None:
    model, data = world
    boxes = np.array([[1.0, 2.0, 0.5, 0.4, 0.3, 0.25], [-1.0, 0.5, -2.0, 1.0, 0.2, 0.4]])
    rgba = np.array([[1, 0, 0, 1], [0, 0, 1, 1]], float)
    set_objects(model, data, boxes, rgba)
    geoms = object_slot_geoms(model)
    assert len(geoms) == SLOTS
    np.testing.assert_allclose(get_objects(model, data), boxes, atol=1e-12)
    np.testing.assert_allclose(data.geom_xpos[geoms[:2], 2], [0.125, 0.2])  # standing on the ground
    np.testing.assert_array_equal(model.geom_group[geoms], [OBJECT_GEOM_GROUP] * 2 + [HIDDEN_GEOM_GROUP] * 6)
    np.testing.assert_allclose(model.geom_rgba[geoms[:2]], rgba)
    assert np.all(data.geom_xpos[geoms[2:], 2] < -10)
    set_objects(model, data, boxes[1:])
    np.testing.assert_allclose(get_objects(model, data), boxes[1:], atol=1e-12)
