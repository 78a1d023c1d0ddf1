"""Deploy: export to ONNX (parity with torch), the on-car runtime's preprocessing (identical to training), the
vehicle calibration (hand-computed outputs), and the runtime driven by a video recorded in our simulator."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from collections import Counter
from pathlib import Path
from unittest import mock

import cv2
import numpy as np
import onnxruntime as ort
import pytest
import torch

from common.action_space import ActionSpace
from common.car_calibration import CarCalibration
from common.config import EnvConfig
from common.defaults import DEFAULT_TRACK
from common.framestack import FrameStack
from common.policy import ActorCritic, action_space_spec, build_policy
from common.sensors import lidar_from_ranges, observation_spec
from common.weights import checkpoint_to_bytes, load_policy
from deploy.car.model_file import ExportError, model_info, model_observation
from deploy.car.runtime import CsvSink, DeployError, Policy, drive, preprocess, preprocess_stereo
from deploy.car.vehicle import (
    VehicleCalibration,
    VehicleCalibrationError,
    load_vehicle_calibration,
    steering_output,
    throttle_output,
)
from deploy.export import export_onnx
from model_store import RunStore, open_store
from racer.runconfig import build_run
from sim.env import RacerEnv

CONTINUOUS = {
    "action_space_type": "continuous",
    "action_space": {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 2.0}},
}


def make_run(
    tmp: Path, run_id: str, action_space: dict | None = None, stack_size: int = 1, greedy: str = "mean"
) -> RunStore:
    """A run in a local store with one checkpoint: a seeded policy whose head is scaled up, so that its choices
    differ clearly from frame to frame (a fresh policy is nearly uniform and its argmax would be a coin toss)."""
    space = None
    if action_space:
        (tmp / "space.json").write_text(json.dumps(action_space))
        space = str(tmp / "space.json")
    (tmp / "hp.json").write_text(json.dumps({"stack_size": stack_size, "greedy_action": greedy}))
    run, files = build_run(run_id, track=DEFAULT_TRACK, action_space=space, hyperparams=str(tmp / "hp.json"))
    runs = RunStore(open_store(str(tmp / "store")))
    for name, data in files.items():
        runs.write_file(run_id, name, data)
    runs.write_file(run_id, "config.json", run.model_dump_json())
    torch.manual_seed(3)
    actions = ActionSpace.model_validate_json(files["model_metadata.json"])
    model = build_policy((120, 160, stack_size), action_space_spec(actions), run.policy)
    with torch.no_grad():
        model.policy_head.weight.mul_(300.0)
    runs.save_checkpoint(run_id, 0, checkpoint_to_bytes(model.state_dict()), {"env_steps": 0})
    return runs


def stored_policy(runs: RunStore, run_id: str) -> ActorCritic:
    """The run's latest checkpoint's network, as ``racer export`` loads it."""
    actions = ActionSpace.model_validate_json(runs.read_file(run_id, "model_metadata.json"))
    return load_policy(runs, run_id, actions, "latest", frame=(120, 160))[0]


def sim_frames(n: int, seed: int = 0) -> list[np.ndarray]:
    """Camera frames (120, 160, 1) from our simulator, driving straight-ish from a few starts."""
    env = RacerEnv(config=EnvConfig(track=DEFAULT_TRACK))
    frames, _ = [], None
    obs, _ = env.reset(seed=seed)
    for i in range(n):
        frames.append(obs)
        obs, _, term, trunc, _ = env.step(i % 3 + 3)
        if term or trunc:
            obs, _ = env.reset()
    env.close()
    return frames


@pytest.mark.parametrize(("space", "stack"), [(None, 1), (CONTINUOUS, 2)], ids=["discrete", "continuous-stack2"])
def test_onnx_export_matches_torch(tmp_path, space, stack):
    runs = make_run(tmp_path, "exp", space, stack)
    result = export_onnx(runs, "exp", "latest", tmp_path / "out" / "model.onnx")
    assert (tmp_path / "out" / "model_metadata.json").read_bytes() == runs.read_file("exp", "model_metadata.json")
    assert model_info(result["model"])["stack_size"] == stack and result["version"] == 0
    model = stored_policy(runs, "exp")
    frames = sim_frames(12)
    obs = np.stack([np.concatenate(frames[i : i + stack], axis=-1) for i in range(10)])  # (10, 120, 160, stack)
    session = ort.InferenceSession(result["model"], providers=["CPUExecutionProvider"])
    onnx_params, onnx_value = session.run(None, {"obs": obs})
    with torch.no_grad():
        params, value = model(torch.from_numpy(obs))
    expected = torch.softmax(params, -1) if space is None else params
    # Float32 sums in another order: probabilities agree to 1e-5, a continuous mean to 1e-4 degrees or m/s.
    np.testing.assert_allclose(onnx_params, expected.numpy(), rtol=1e-5, atol=1e-5 if space is None else 1e-4)
    np.testing.assert_allclose(onnx_value, value.numpy(), rtol=1e-5, atol=1e-4)
    if space is None:  # the greedy actions agree, and they are not all the same action
        assert (onnx_params.argmax(1) == expected.numpy().argmax(1)).all()
        assert len(set(onnx_params.argmax(1))) > 1


def test_onnx_export_gives_the_censored_mean_with_greedy_action_expected(tmp_path):
    runs = make_run(tmp_path, "exp", CONTINUOUS, 1, greedy="expected")
    result = export_onnx(runs, "exp", "latest", tmp_path / "out" / "model.onnx")
    model = stored_policy(runs, "exp")
    assert model.cfg.greedy_action == "expected"
    obs = np.stack(sim_frames(8))
    onnx_action, _ = ort.InferenceSession(result["model"], providers=["CPUExecutionProvider"]).run(None, {"obs": obs})
    torch_action, _, _ = model.act_numpy(obs, deterministic=True)
    with torch.no_grad():
        mean, _ = model(torch.from_numpy(obs))
    np.testing.assert_allclose(onnx_action, torch_action, rtol=1e-5, atol=1e-4)
    # The scaled-up head puts some means outside the range: there the export differs from the plain mean.
    outside = (mean < torch.tensor([-30.0, 0.5])) | (mean > torch.tensor([30.0, 2.0]))
    assert outside.any() and (np.abs(onnx_action - mean.numpy())[outside.numpy()] > 0.01).all()
    assert ((onnx_action >= [-30.0, 0.5]) & (onnx_action <= [30.0, 2.0])).all()


def test_the_runtime_builds_the_same_tensor_as_training_from_the_same_frame():
    frames = sim_frames(4)
    stack_train, stack_car = FrameStack(2), FrameStack(2)
    for i, frame in enumerate(frames):
        bgr = cv2.cvtColor(frame[..., 0], cv2.COLOR_GRAY2BGR)  # what a camera or a video hands the runtime
        big = cv2.resize(bgr, (640, 480), interpolation=cv2.INTER_NEAREST)  # a camera at 4× the resolution
        for delivered in (bgr, big, frame):
            np.testing.assert_array_equal(preprocess(delivered), frame[..., 0])
        train = stack_train.reset(frame) if i == 0 else stack_train.push(frame)
        car_frame = preprocess(big)[..., None]
        car = stack_car.reset(car_frame) if i == 0 else stack_car.push(car_frame)
        assert car.dtype == train.dtype == np.uint8
        np.testing.assert_array_equal(car, train)


def test_the_mujoco_camera_path_matches_too():
    """With the MuJoCo camera the env converts an RGB render with OpenCV; the runtime converts the camera's BGR."""
    try:
        env = RacerEnv(config=EnvConfig(track=DEFAULT_TRACK, camera="mujoco"))
        obs, _ = env.reset(seed=1)
        rgb = env.camera.render(env.physics.pose, color=True)
    except Exception as exc:  # no OpenGL context on this machine or in this process
        pytest.skip(f"MuJoCo rendering is unavailable here: {type(exc).__name__}: {exc}")
    env.close()
    np.testing.assert_array_equal(preprocess(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)), obs[..., 0])


def test_vehicle_calibration_maps_actions_to_hand_computed_outputs(tmp_path):
    cal = VehicleCalibration.model_validate(
        {
            "steering": {"center": 1500, "left": 1900, "right": 1100, "max_angle_deg": 30},
            "throttle": {"stop": 1500, "full": 1800, "curve": [[0, 0], [2, 0.4], [4, 1.0]], "max_speed_pct": 50},
        }
    )
    assert steering_output(cal, 0) == 1500
    assert steering_output(cal, 15) == pytest.approx(1700)  # half of the left travel
    assert steering_output(cal, -30) == pytest.approx(1100)
    assert steering_output(cal, -45) == pytest.approx(1100)  # beyond full lock: clipped
    assert throttle_output(cal, 1.0) == pytest.approx(1500 + 0.2 * 0.5 * 300)  # curve 0.2, half speed: 1530
    assert throttle_output(cal, 3.0) == pytest.approx(1500 + 0.7 * 0.5 * 300)  # 1605
    # Fitted effects of this car: it steers 0.8 × the command + 1°, and runs at 0.5 × the commanded speed.
    effects = CarCalibration.from_values(
        {"steering_gain": {"gain": 0.8}, "steering_offset": {"offset_deg": 1.0}, "speed_gain": {"gain": 0.5}}
    )
    cal = cal.model_copy(update={"car": effects})
    assert steering_output(cal, 9.0) == pytest.approx(1500 + (10.0 / 30) * 400)  # asks (9 - 1) / 0.8 = 10°
    assert throttle_output(cal, 1.0) == pytest.approx(1500 + 0.4 * 0.5 * 300)  # asks 2 m/s: curve 0.4

    for text, where in (
        ('{"steering": {"max_angle_deg": -5}}', "steering.max_angle_deg"),
        ('{"throttle": {"curve": [[1, 0.5], [1, 0.6]]}}', "throttle"),
        ('{"steer": {}}', "steer"),
        ("[1]", "expected a JSON object"),
    ):
        (tmp_path / "v.json").write_text(text)
        with pytest.raises(VehicleCalibrationError, match=where) as err:
            load_vehicle_calibration(tmp_path / "v.json")
        assert "v.json" in str(err.value) and "\n" not in str(err.value)


def record_sim_video(runs: RunStore, path: Path, steps: int) -> list[int]:
    """Drive our simulator greedily with the torch policy, record its camera losslessly (FFV1), return the actions."""
    model = stored_policy(runs, "car")
    env = RacerEnv(config=EnvConfig(track=DEFAULT_TRACK))
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 15, (160, 120), isColor=False)
    assert writer.isOpened(), "OpenCV's FFV1 (lossless) encoder should be available"
    obs, _ = env.reset(seed=5)
    actions = []
    for _ in range(steps):
        writer.write(obs[..., 0])
        action = int(model.act_numpy(obs[None], deterministic=True)[0][0])
        actions.append(action)
        obs, _, term, trunc, _ = env.step(action)
        if term or trunc:
            obs, _ = env.reset()
    writer.release()
    env.close()
    return actions


@pytest.mark.slow(reason="starts real racer processes")
def test_the_runtime_on_a_sim_video_commands_what_the_policy_chose(tmp_path):
    runs = make_run(tmp_path, "car")
    model = tmp_path / "model.onnx"
    export_onnx(runs, "car", "latest", model)
    actions = record_sim_video(runs, tmp_path / "drive.avi", 90)
    # The policy really steers differently along the way: at least two actions, each for several frames. (This asked
    # for 3 actions on reinvent_base, which the seeded network reached by one frame of a third; on racer_loop, with
    # reset seed 5, it chooses actions 2 and 3 only. Over reset seeds 0-7, on either track, the second most chosen
    # action takes 10-21 of the 90 frames and any other at most 2.)
    counts = sorted(Counter(actions).values())
    assert len(counts) >= 2 and counts[-2] >= 5, actions
    vehicle = {"steering": {"center": 1450, "left": 1850, "right": 1000}, "throttle": {"max_speed_pct": 80}}
    (tmp_path / "vehicle.json").write_text(json.dumps(vehicle))
    out = subprocess.run(
        [sys.executable, "-m", "racer", "car", "--model", str(model), "--source", str(tmp_path / "drive.avi"),
         "--vehicle", str(tmp_path / "vehicle.json"), "--out", str(tmp_path / "cmds.csv"), "--json", "-"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["frames"] == len(actions)
    rows = list(csv.DictReader((tmp_path / "cmds.csv").open()))
    space = ActionSpace.model_validate_json(runs.read_file("car", "model_metadata.json"))
    cal = VehicleCalibration.model_validate(vehicle)
    assert [int(r["action"]) for r in rows] == actions
    for row, action in zip(rows, actions, strict=True):
        steering, speed = space.command(action)
        assert float(row["steering_out"]) == pytest.approx(steering_output(cal, steering))
        assert float(row["throttle_out"]) == pytest.approx(throttle_output(cal, speed))


@pytest.mark.slow(reason="starts real racer processes")
def test_runtime_and_export_refuse_bad_input_in_one_line(tmp_path):
    (tmp_path / "not.onnx").write_bytes(b"not a model")
    with pytest.raises(ExportError, match="not.onnx"):
        Policy(tmp_path / "not.onnx")
    for args, expected in (
        (["car", "--model", "missing.onnx", "--source", "x.avi"], "missing.onnx"),
        (["car", "--model", "not.onnx", "--source", "x.avi"], "not an ONNX model"),
        (["export", "--run-id", "nope", "-o", "m.onnx"], "run 'nope' does not exist"),
        (["export", "--run-id", "nope", "-o", "m.onnx", "--format", "tflite"], "--format 'tflite'"),
    ):
        out = subprocess.run([sys.executable, "-m", "racer", *args], cwd=tmp_path, capture_output=True, text=True)
        assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr
        assert expected in out.stderr and "Traceback" not in out.stderr


def test_the_runtime_needs_no_torch():
    """A car carries onnxruntime and OpenCV, not PyTorch: importing the runtime must not import torch."""
    code = "import sys, deploy.car.runtime, deploy.car.vehicle; sys.exit('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


# --- other sensors: stereo cameras and LiDAR (common.sensors) -----------------------------------------------------


def make_sensor_run(tmp: Path, run_id: str, sensors: list[str], stack_size: int = 1) -> RunStore:
    """``make_run`` for another sensor list: the run's model_metadata.json names the sensors, and its checkpoint is a
    seeded network for them with a scaled-up head (choices that differ clearly from input to input)."""
    (tmp / "hp.json").write_text(json.dumps({"stack_size": stack_size}))
    run, files = build_run(run_id, track=DEFAULT_TRACK, hyperparams=str(tmp / "hp.json"))
    actions = ActionSpace.model_validate_json(files["model_metadata.json"]).model_copy(update={"sensor": sensors})
    files["model_metadata.json"] = actions.to_json().encode()
    runs = RunStore(open_store(str(tmp / "store")))
    for name, data in files.items():
        runs.write_file(run_id, name, data)
    runs.write_file(run_id, "config.json", run.model_dump_json())
    torch.manual_seed(4)
    shape = observation_spec(sensors, stack_size).camera_shape((120, 160))
    with mock.patch.object(torch.nn.init, "orthogonal_", lambda tensor, gain=1.0: tensor):  # no QR of 11520×512
        model = build_policy(shape, action_space_spec(actions), run.policy, sensors)
    with torch.no_grad():
        model.policy_head.weight.mul_(300.0)
    runs.save_checkpoint(run_id, 0, checkpoint_to_bytes(model.state_dict()), {"env_steps": 0})
    return runs


def sensor_inputs(spec, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray | None]:
    """``n`` camera observations (stereo: two different sim frames as left and right) and LiDAR vectors."""
    frames = sim_frames(n + spec.stack_size + 1, seed)
    per_frame = [
        np.concatenate([frames[i], frames[i + 1]], axis=-1) if spec.frame_channels == 2 else frames[i]
        for i in range(len(frames) - 1)
    ]
    obs = np.stack([np.concatenate(per_frame[i : i + spec.stack_size], axis=-1) for i in range(n)])
    rng = np.random.default_rng(seed)
    scans = rng.uniform(0.1, 1.5, (n, 64))
    lidar = np.stack([lidar_from_ranges(spec.lidar.name, s) for s in scans]) if spec.lidar else None
    return obs, lidar


@pytest.mark.parametrize(
    ("sensors", "stack"),
    [(["STEREO_CAMERAS", "LIDAR"], 1), (["FRONT_FACING_CAMERA", "SECTOR_LIDAR"], 2), (["STEREO_CAMERAS"], 2)],
    ids=["stereo+lidar", "front+sector-stack2", "stereo-stack2"],
)
def test_onnx_export_of_other_sensors_matches_torch(tmp_path, sensors, stack):
    runs = make_sensor_run(tmp_path, "exp", sensors, stack)
    result = export_onnx(runs, "exp", "latest", tmp_path / "out" / "model.onnx")
    info = model_info(result["model"])
    spec = observation_spec(sensors, stack)
    assert info["sensors"] == list(spec.sensors) and info["obs_shape"] == [120, 160, spec.camera_channels]
    assert info.get("lidar_shape") == ([spec.lidar_size] if spec.lidar else None)
    session = ort.InferenceSession(result["model"], providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == (["obs", "lidar"] if spec.lidar else ["obs"])
    model = stored_policy(runs, "exp")
    obs, lidar = sensor_inputs(spec, 8)
    feed = {"obs": obs} | ({"lidar": lidar} if spec.lidar else {})
    onnx_probs, onnx_value = session.run(None, feed)
    with torch.no_grad():
        logits, value = model(torch.from_numpy(obs), None if lidar is None else torch.from_numpy(lidar))
    np.testing.assert_allclose(onnx_probs, torch.softmax(logits, -1).numpy(), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(onnx_value, value.numpy(), rtol=1e-5, atol=1e-4)
    if spec.lidar:  # the exported graph reads its LiDAR input: the same frames with other scans choose otherwise
        other = np.stack([lidar_from_ranges(spec.lidar.name, np.full(64, r)) for r in np.linspace(0.1, 2.0, 8)])
        probs_other, _ = session.run(None, {"obs": np.repeat(obs[:1], 8, axis=0), "lidar": other})
        assert np.abs(probs_other - probs_other[0]).max() > 1e-3


class ScanList:
    """A LidarSource replaying scans (64 ranges each)."""

    def __init__(self, scans: np.ndarray) -> None:
        self.scans, self.i = scans, 0

    def read(self) -> np.ndarray:
        self.i += 1
        return self.scans[self.i - 1]


def test_the_runtime_drives_a_stereo_lidar_model_as_torch_chooses(tmp_path):
    sensors = ["STEREO_CAMERAS", "LIDAR"]
    runs = make_sensor_run(tmp_path, "car", sensors)
    model_path = tmp_path / "model.onnx"
    export_onnx(runs, "car", "latest", model_path)
    model = stored_policy(runs, "car")
    frames = sim_frames(31)
    rng = np.random.default_rng(1)
    scans = rng.uniform(0.1, 1.5, (30, 64))
    scans[rng.random((30, 64)) < 0.1] = np.inf
    for side, offset in (("left", 0), ("right", 1)):  # right: the next sim frame, so the two images differ
        writer = cv2.VideoWriter(str(tmp_path / f"{side}.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 15, (160, 120), False)
        for frame in frames[offset : offset + 30]:
            writer.write(frame[..., 0])
        writer.release()
    expected = []
    for i in range(30):
        obs = np.concatenate([frames[i], frames[i + 1]], axis=-1)[None]
        lidar = lidar_from_ranges("LIDAR", scans[i])[None]
        expected.append(int(model.act_numpy(obs, deterministic=True, lidar=lidar)[0][0]))
    assert len(set(expected)) > 1, expected
    policy = Policy(model_path)
    assert policy.spec.sensors == ("STEREO_CAMERAS", "LIDAR") and policy.obs_shape == (120, 160, 2)
    sink = CsvSink(tmp_path / "cmds.csv")
    result = drive(
        policy, str(tmp_path / "left.avi"), VehicleCalibration(), sink, right_source=str(tmp_path / "right.avi"),
        lidar=ScanList(scans),
    )  # fmt: skip
    assert result.frames == 30
    rows = list(csv.DictReader((tmp_path / "cmds.csv").open()))
    assert [int(r["action"]) for r in rows] == expected
    # What the model needs, the runtime asks for, in one line.
    obs = np.concatenate([frames[0], frames[1]], axis=-1)
    with pytest.raises(DeployError, match="need a LiDAR vector"):
        policy.act(obs)
    with pytest.raises(DeployError, match=r"values outside \[0.15, 1.0\]"):
        policy.act(obs, np.full(64, 5.0, np.float32))
    with pytest.raises(DeployError, match=r"takes \(120, 160, 2\) uint8"):
        policy.act(frames[0], lidar_from_ranges("LIDAR", scans[0]))
    for kwargs, message in (
        ({"lidar": ScanList(scans)}, "give the right camera too"),
        ({"right_source": str(tmp_path / "right.avi")}, "give a LiDAR"),
    ):
        with pytest.raises(DeployError, match=message):
            drive(policy, str(tmp_path / "left.avi"), VehicleCalibration(), CsvSink(tmp_path / "x.csv"), **kwargs)


def test_preprocess_stereo_is_each_camera_preprocessed_left_then_right():
    frames = sim_frames(2)
    left, right = (cv2.resize(cv2.cvtColor(f[..., 0], cv2.COLOR_GRAY2BGR), (640, 480)) for f in frames)
    pair = preprocess_stereo(left, right)
    assert pair.shape == (120, 160, 2) and pair.dtype == np.uint8
    np.testing.assert_array_equal(pair[..., 0], preprocess(left))
    np.testing.assert_array_equal(pair[..., 1], preprocess(right))


def test_a_model_exported_before_sensors_is_a_front_camera_model():
    assert model_observation({"stack_size": 3}).sensors == ("FRONT_FACING_CAMERA",)
    assert model_observation({"stack_size": 1, "sensors": ["LIDAR", "STEREO_CAMERAS"]}).lidar_size == 64
    with pytest.raises(ExportError, match="exactly one camera"):
        model_observation({"stack_size": 1, "sensors": ["LIDAR"]})
