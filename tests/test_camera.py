"""Tests of the car cameras (sim.camera, sim.mujoco_camera): image content, geometry, and the fast GroundCamera
against MuJoCo's own OpenGL render (MujocoCamera, the reference), boxes included; the boxes' own drawing is
tests/test_box_raster.py."""

from __future__ import annotations

import math
import time

import cv2
import numpy as np
import pytest

import sim  # noqa: F401  (first: picks MuJoCo's GL backend, EGL when headless, before mujoco is imported)
from common.defaults import DEFAULT_TRACK
from sim.camera import CameraSpec, GroundCamera
from sim.env import RacerEnv
from sim.mujoco_camera import MujocoCamera, RenderError
from sim.physics import Pose
from sim.texture import DEEPRACER_PALETTE

TRACK = DEFAULT_TRACK
STRAIGHTEST = 109
"""racer_loop's straightest waypoint for a camera: its centre line bends at radius 4.3 m or more from 0.3 m behind
it to 2.4 m ahead, the widest of any waypoint (reinvent_base's waypoint 3, which these tests used, is on a true
straight; racer_loop has none). Found by the curvature at each waypoint over that window."""
H, W = 120, 160
AGREEMENT_POSES = [(0, False), (20, True), (45, False), (70, True), (100, False)]
"""(start waypoint, reversed) of the poses where both cameras are compared."""


def pinned(index: int, reverse: bool = False) -> dict:
    return {"start_index": index, "reverse": reverse}


@pytest.fixture(scope="module")
def env() -> RacerEnv:
    return RacerEnv(track=TRACK)


@pytest.fixture(scope="module")
def centre_pose(env: RacerEnv) -> Pose:
    """base_link on the centre line at the straightest waypoint of the track, facing along it."""
    env.reset(seed=0, options=pinned(STRAIGHTEST))
    return env.physics.pose


@pytest.fixture(scope="module")
def camera(env: RacerEnv) -> GroundCamera:
    return GroundCamera(env.frame, env.texture, CameraSpec(), DEEPRACER_PALETTE.sky)


@pytest.fixture(scope="module")
def mujoco_env():
    try:
        env = RacerEnv(track=TRACK, camera="mujoco")
    except RenderError as exc:
        pytest.skip(str(exc))
    assert isinstance(env.camera, MujocoCamera)
    yield env
    env.close()


def abs_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a.astype(np.int16) - b.astype(np.int16))


# --- GroundCamera against MuJoCo's render ---------------------------------------------------------------


@pytest.mark.parametrize(("index", "reverse"), AGREEMENT_POSES)
def test_ground_camera_agrees_with_mujoco_render(mujoco_env: RacerEnv, index: int, reverse: bool) -> None:
    mujoco_env.reset(seed=0, options=pinned(index, reverse))
    ground = GroundCamera(mujoco_env.frame, mujoco_env.texture)
    fast = ground.render(mujoco_env.physics.pose)
    reference = mujoco_env.camera.render()
    assert fast.shape == reference.shape == (H, W)
    assert fast.std() > 10 and reference.std() > 10  # not blank: agreement means something
    diff = abs_diff(fast, reference)
    # Measured on racer_loop: mean 1.8-2.3 gray levels, median 0, 95th percentile 9-12 (edges of lines).
    assert diff.mean() < 6, diff.mean()
    assert np.percentile(diff, 95) < 40, np.percentile(diff, 95)
    assert np.median(diff) <= 1
    # The sky (top rows) is the same colour in both.
    assert np.abs(fast[:30].astype(int) - reference[:30].astype(int)).max() <= 2


@pytest.mark.parametrize(
    "spec",
    [CameraSpec(yaw_deg=10), CameraSpec(pitch_deg=20, roll_deg=3, left_m=0.02, up_m=0.1)],
    ids=["yaw", "moved"],
)
def test_ground_camera_agrees_with_mujoco_for_moved_camera(mujoco_env: RacerEnv, spec: CameraSpec) -> None:
    mujoco_env.camera.set_spec(spec)
    try:
        mujoco_env.reset(seed=0, options=pinned(10))
        fast = GroundCamera(mujoco_env.frame, mujoco_env.texture, spec).render(mujoco_env.physics.pose)
        reference = mujoco_env.camera.render()
    finally:
        mujoco_env.camera.set_spec(CameraSpec())
    diff = abs_diff(fast, reference)
    assert reference.std() > 10
    assert diff.mean() < 6 and np.percentile(diff, 95) < 40, (diff.mean(), np.percentile(diff, 95))


def test_ground_camera_colour_agrees_with_mujoco(mujoco_env: RacerEnv) -> None:
    mujoco_env.reset(seed=0, options=pinned(10))
    fast = GroundCamera(mujoco_env.frame, mujoco_env.texture).render(mujoco_env.physics.pose, color=True)
    reference = mujoco_env.camera.render(color=True)
    assert fast.shape == reference.shape == (H, W, 3)
    diff = abs_diff(fast, reference)
    assert diff.mean() < 6 and np.percentile(diff, 95) < 40, (diff.mean(), np.percentile(diff, 95))


def test_mujoco_render_after_step_shows_current_state(mujoco_env: RacerEnv) -> None:
    import mujoco

    mujoco_env.reset(seed=0, options=pinned(10))
    for _ in range(10):
        mujoco_env.step(9)  # 30° left at 1 m/s
    after_step = mujoco_env.camera.render()
    physics = mujoco_env.physics
    mujoco.mj_forward(physics.model, physics.data)  # recompute positions from qpos: changes no state
    np.testing.assert_array_equal(after_step, mujoco_env.camera.render())


def test_wheel_positions_after_step_are_current(env: RacerEnv) -> None:
    import mujoco

    env.reset(seed=0, options=pinned(10))
    for _ in range(10):
        env.step(9)
    physics = env.physics
    wheels = physics.wheel_positions()
    mujoco.mj_forward(physics.model, physics.data)
    np.testing.assert_allclose(wheels, physics.wheel_positions(), atol=1e-6)


# --- image content --------------------------------------------------------------------------------------


def test_image_is_gray_uint8_of_camera_size(env: RacerEnv, camera: GroundCamera, centre_pose: Pose) -> None:
    img = camera.render(centre_pose)
    assert img.shape == (H, W) and img.dtype == np.uint8
    obs, _ = env.reset(seed=0, options=pinned(STRAIGHTEST))
    assert obs.shape == (H, W, 1) and obs.dtype == np.uint8
    np.testing.assert_array_equal(obs[..., 0], img)


def test_sky_is_uniform(camera: GroundCamera, centre_pose: Pose) -> None:
    img = camera.render(centre_pose)
    sky = img[:40]
    assert np.unique(sky).size == 1
    sky_gray = cv2.cvtColor(np.array([[DEEPRACER_PALETTE.sky]], np.uint8), cv2.COLOR_RGB2GRAY)[0, 0]
    assert abs(int(sky[0, 0]) - int(sky_gray)) <= 1
    # Below the horizon the ground is not uniform.
    assert np.unique(img[60:]).size > 10


def test_road_is_darker_than_border_lines(camera: GroundCamera, centre_pose: Pose) -> None:
    img = camera.render(centre_pose)
    bottom = img[-30:]
    road_gray = cv2.cvtColor(np.array([[DEEPRACER_PALETTE.road]], np.uint8), cv2.COLOR_RGB2GRAY)[0, 0]
    # On the centre line the bottom of the frame is road, apart from the centre dash in the middle columns.
    bright_cols = np.nonzero((bottom >= 90).any(axis=0))[0]
    assert bright_cols.size == 0 or (bright_cols.min() >= W // 2 - 25 and bright_cols.max() <= W // 2 + 25)
    side = np.concatenate([bottom[:, : W // 2 - 25], bottom[:, W // 2 + 25 :]], axis=1)
    assert side.max() < 90
    assert abs(float(np.median(side)) - road_gray) <= 2
    # The white border lines are in the lower half, on both sides.
    lower = img[H // 2 :]
    bright = lower > 200
    assert bright.sum() > 50
    cols = np.nonzero(bright.any(axis=0))[0]
    assert cols.min() < W // 3 and cols.max() > 2 * W // 3


def test_centre_dash_seen_ahead(camera: GroundCamera, centre_pose: Pose) -> None:
    """Somewhere along the centre column below the horizon there is a dash (bright) and a gap (dark)."""
    column = camera.render(centre_pose)[H // 2 :, W // 2 - 1 : W // 2 + 1].min(axis=1)
    assert column.max() > 150 and column.min() < 90


def test_rgb_render_matches_gray(camera: GroundCamera, centre_pose: Pose) -> None:
    rgb = camera.render(centre_pose, color=True)
    gray = camera.render(centre_pose)
    assert rgb.shape == (H, W, 3) and rgb.dtype == np.uint8
    assert abs_diff(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), gray).max() <= 2
    # At this pose a centre dash is at the bottom centre: it is yellow (red and green well above blue).
    r, g, b = (int(v) for v in rgb[-5, W // 2])
    assert r > b + 50 and g > b + 50, (r, g, b)


def test_moving_forward_changes_image(camera: GroundCamera, centre_pose: Pose) -> None:
    p = centre_pose
    ahead = Pose(p.x + 0.5 * math.cos(p.yaw), p.y + 0.5 * math.sin(p.yaw), p.yaw)
    before, after = camera.render(p), camera.render(ahead)
    assert abs_diff(before, after).mean() > 2
    # The sky does not move.
    np.testing.assert_array_equal(before[:40], after[:40])
    # Rendering is a pure function of the pose.
    np.testing.assert_array_equal(camera.render(p), before)


def correlation_peak(a: np.ndarray, b: np.ndarray, max_shift: int = 30) -> int:
    """Horizontal shift (pixels, + = content of ``b`` to the right of ``a``) of best normalized correlation."""
    a = a.astype(np.float64) - a.mean()
    b = b.astype(np.float64) - b.mean()

    def corr(s: int) -> float:
        x, y = (a[:, : W - s], b[:, s:]) if s >= 0 else (a[:, -s:], b[:, : W + s])
        return float((x * y).sum() / np.sqrt((x * x).sum() * (y * y).sum()))

    shifts = range(-max_shift, max_shift + 1)
    return list(shifts)[int(np.argmax([corr(s) for s in shifts]))]


def test_camera_yaw_shifts_image_horizontally(env: RacerEnv, camera: GroundCamera, centre_pose: Pose) -> None:
    plain = camera.render(centre_pose)[H // 2 :]
    assert correlation_peak(plain, plain) == 0
    expected = CameraSpec().focal_px * math.tan(math.radians(10))  # about 8 px near the image centre
    left = GroundCamera(env.frame, env.texture, CameraSpec(yaw_deg=10)).render(centre_pose)[H // 2 :]
    right = GroundCamera(env.frame, env.texture, CameraSpec(yaw_deg=-10)).render(centre_pose)[H // 2 :]
    # Turning the camera left moves the scene to the right in the image, and vice versa.
    shift_left, shift_right = correlation_peak(plain, left), correlation_peak(plain, right)
    assert 0.5 * expected <= shift_left <= 1.5 * expected, shift_left
    assert -1.5 * expected <= shift_right <= -0.5 * expected, shift_right


def test_set_spec_moves_existing_camera(env: RacerEnv, centre_pose: Pose) -> None:
    cam = GroundCamera(env.frame, env.texture)
    plain = cam.render(centre_pose)
    cam.set_spec(CameraSpec(yaw_deg=10))
    np.testing.assert_array_equal(
        cam.render(centre_pose), GroundCamera(env.frame, env.texture, CameraSpec(yaw_deg=10)).render(centre_pose)
    )
    cam.set_spec(CameraSpec())
    np.testing.assert_array_equal(cam.render(centre_pose), plain)


# --- CameraSpec geometry --------------------------------------------------------------------------------


def test_camera_spec_defaults() -> None:
    spec = CameraSpec()
    assert (spec.width, spec.height, spec.hfov_deg) == (160, 120, 120.0)
    assert spec.focal_px == pytest.approx(80 / math.tan(math.radians(60)))
    assert spec.focal_px == pytest.approx(46.188, abs=1e-3)
    assert spec.fovy_deg == pytest.approx(104.8, abs=0.05)
    assert spec.fovy_deg == pytest.approx(math.degrees(2 * math.atan(60 / spec.focal_px)))


def test_camera_spec_rotation_and_rays() -> None:
    spec = CameraSpec()
    rot = spec.rotation()
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    # Forward axis pitched 15° down.
    fwd = rot[:, 0]
    assert math.degrees(math.atan2(-fwd[2], fwd[0])) == pytest.approx(15.0)
    rays = spec.rays()
    assert rays.shape == (120, 160, 3)
    # Left of the image looks left (+y), the top looks up.
    assert rays[60, 0, 1] > 0 > rays[60, -1, 1]
    assert rays[0, 80, 2] > rays[-1, 80, 2]
    # Corner rays subtend half the horizontal field of view.
    centre = rot[:, 0]
    edge = (rays[59, 0] + rays[60, 0]) / 2
    half = math.degrees(math.acos(edge @ centre / np.linalg.norm(edge)))
    assert half == pytest.approx(60.0, abs=0.5)


def test_camera_spec_jitter_bounds() -> None:
    rng = np.random.default_rng(0)
    nominal = CameraSpec()
    for _ in range(50):
        spec = nominal.jittered(rng, 0.02, 4.0)
        assert abs(spec.forward_m - nominal.forward_m) <= 0.02
        assert abs(spec.left_m - nominal.left_m) <= 0.02
        assert abs(spec.up_m - nominal.up_m) <= 0.02
        assert abs(spec.pitch_deg - nominal.pitch_deg) <= 4.0
        assert abs(spec.yaw_deg - nominal.yaw_deg) <= 4.0
        assert abs(spec.roll_deg - nominal.roll_deg) <= 4.0
        assert (spec.width, spec.height, spec.hfov_deg) == (nominal.width, nominal.height, nominal.hfov_deg)
    assert nominal.jittered(rng, 0.0, 0.0) == nominal


# --- speed ----------------------------------------------------------------------------------------------


def test_ground_camera_is_fast(camera: GroundCamera, centre_pose: Pose) -> None:
    camera.render(centre_pose)
    start = time.perf_counter()
    for k in range(200):
        camera.render(Pose(centre_pose.x + 0.001 * k, centre_pose.y, centre_pose.yaw))
    assert time.perf_counter() - start < 2.0


# --- objects (boxes) and the stereo pair ----------------------------------------------------------------

WHITE = np.array([[255.0, 255.0, 255.0]])


def box_ahead(pose: Pose, forward: float, left: float = 0.0, yaw: float = 0.0, size=(0.4, 0.3, 0.25)) -> list[float]:
    """[x, y, yaw, length, width, height] of a box centred ``forward``/``left`` metres from base_link, in the car's
    frame turned by ``yaw``."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    return [pose.x + c * forward - s * left, pose.y + s * forward + c * left, pose.yaw + yaw, *size]


def raycast_mask(spec: CameraSpec, pose: Pose, boxes: np.ndarray) -> np.ndarray:
    """(H, W) pixels whose centre ray hits one of ``boxes``: an independent per-pixel 3D ray-box test."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    car = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    rays = spec.rays().reshape(-1, 3) @ car.T
    origin = np.array([pose.x, pose.y, 0.0]) + car @ spec.position
    hit = np.zeros(len(rays), bool)
    for x, y, yaw, length, width, height in boxes:
        cb, sb = math.cos(yaw), math.sin(yaw)
        to_box = np.array([[cb, sb, 0.0], [-sb, cb, 0.0], [0.0, 0.0, 1.0]])  # world -> box frame
        o = to_box @ (origin - (x, y, 0.0))
        d = rays @ to_box.T
        lo, hi = np.array([-length / 2, -width / 2, 0.0]), np.array([length / 2, width / 2, height])
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (lo - o) / d, (hi - o) / d
        enter = np.nanmax(np.minimum(t1, t2), axis=1)
        leave = np.nanmin(np.maximum(t1, t2), axis=1)
        hit |= (enter <= leave) & (leave > 0)
    return hit.reshape(spec.height, spec.width)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def test_ground_and_mujoco_cameras_agree_on_boxes(env: RacerEnv) -> None:
    from sim.physics import CarPhysics
    from sim.world import build_model, set_objects

    model = build_model(env.frame, env.texture, DEEPRACER_PALETTE.sky, object_slots=4)
    physics = CarPhysics(model)
    env.reset(seed=0, options=pinned(STRAIGHTEST))
    physics.reset(env.physics.pose)
    try:
        reference = MujocoCamera(model, physics.data)
    except RenderError as exc:
        pytest.skip(str(exc))
    try:
        pose = physics.pose
        boxes = np.array(
            [
                box_ahead(pose, 1.0, 0.15, 0.3),
                box_ahead(pose, 2.0, -0.4, 0.8, (0.4, 0.3, 0.5)),
                box_ahead(pose, 0.6, 0.4),
            ]
        )
        set_objects(model, physics.data, np.zeros((0, 6)))
        ref_plain = reference.render()
        set_objects(model, physics.data, boxes, rgba=np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)))  # unlike sky and road
        ref_boxes = reference.render()
    finally:
        reference.close()
    ground = GroundCamera(env.frame, env.texture)
    fast_plain, fast_boxes = ground.render(pose), ground.render(pose, boxes=boxes, box_colors=np.zeros((3, 3)))
    ref_mask = abs_diff(ref_boxes, ref_plain) > 8
    fast_mask = abs_diff(fast_boxes, fast_plain) > 8
    assert ref_mask.sum() > 1000
    assert iou(ref_mask, fast_mask) > 0.85, iou(ref_mask, fast_mask)
    assert np.median(ref_boxes[ref_mask & fast_mask]) <= 2 and np.median(fast_boxes[ref_mask & fast_mask]) <= 2


# --- stereo ---------------------------------------------------------------------------------------------


def test_stereo_specs_are_the_urdf_pair() -> None:
    from sim.camera import STEREO_BASELINE_M, stereo_specs

    assert STEREO_BASELINE_M == 0.06  # zed_camera_joint_leftcam / _rightcam at y = ±0.03 (deepracer_stereo_cam.urdf)
    left, right = stereo_specs(CameraSpec())
    assert (left.left_m, right.left_m) == (0.03, -0.03)
    assert left.position[1] - right.position[1] == pytest.approx(0.06)
    for spec in (left, right):
        assert spec == CameraSpec(left_m=spec.left_m)  # otherwise the single camera's pose


def test_stereo_is_two_gray_views_left_first(env: RacerEnv, centre_pose: Pose) -> None:
    from sim.camera import StereoGroundCamera, stereo_specs

    stereo = StereoGroundCamera(env.frame, env.texture, sky_rgb=DEEPRACER_PALETTE.sky)
    boxes = np.array([box_ahead(centre_pose, 0.9, 0.1, 0.3), box_ahead(centre_pose, 2.0, -0.3)])
    for bx in (None, boxes):
        img = stereo.render(centre_pose, boxes=bx)
        assert img.shape == (H, W, 2) and img.dtype == np.uint8
        for channel, spec in enumerate(stereo_specs(CameraSpec())):
            single = GroundCamera(env.frame, env.texture, spec, DEEPRACER_PALETTE.sky).render(centre_pose, boxes=bx)
            # The same as a single camera at that pose (box edges may round differently by a pixel here and there).
            assert (img[..., channel] != single).sum() <= (0 if bx is None else 10)
    assert abs_diff(img[..., 0], img[..., 1]).mean() > 1  # 6 cm apart: the views differ
    with pytest.raises(ValueError, match="gray"):
        stereo.render(centre_pose, color=True)


def test_stereo_disparity_of_a_box_at_known_distance(env: RacerEnv, centre_pose: Pose) -> None:
    from sim.camera import STEREO_BASELINE_M, StereoGroundCamera

    stereo = StereoGroundCamera(env.frame, env.texture)
    spec = CameraSpec()
    plain = stereo.render(centre_pose)
    for face_m in (0.35, 0.6, 1.0):  # distance of the box's front face ahead of the camera
        boxes = np.array([box_ahead(centre_pose, spec.forward_m + face_m + 0.1, size=(0.2, 0.3, 0.4))])
        img = stereo.render(centre_pose, boxes=boxes, box_colors=WHITE)
        # A row just above the horizon sees the box at every distance; its ray meets the face at depth (along the
        # optical axis) face / (cos p - v / f sin p), v the row's offset from the image centre.
        row = 47
        v = row - (H - 1) / 2
        p = math.radians(spec.pitch_deg)
        depth = face_m / (math.cos(p) - v / spec.focal_px * math.sin(p))
        edges = []
        for ch in (0, 1):
            cols = np.flatnonzero(img[row, :, ch] != plain[row, :, ch])
            edges.append((cols.min() + cols.max()) / 2)  # the face's centre column
        expected = spec.focal_px * STEREO_BASELINE_M / depth
        assert edges[0] - edges[1] == pytest.approx(expected, abs=0.6), (face_m, edges, expected)


def test_stereo_with_boxes_is_fast(env: RacerEnv, centre_pose: Pose) -> None:
    from sim.camera import StereoGroundCamera

    stereo = StereoGroundCamera(env.frame, env.texture)
    boxes = np.array(
        [box_ahead(centre_pose, d, lat) for d, lat in [(1, 0.1), (2, -0.4), (0.6, 0.35), (-1, 0), (4, 1.5), (-3, 0)]]
    )
    stereo.render(centre_pose, boxes=boxes)
    start = time.perf_counter()
    for k in range(200):
        stereo.render(Pose(centre_pose.x + 0.001 * k, centre_pose.y, centre_pose.yaw), boxes=boxes)
    assert time.perf_counter() - start < 4.0
