"""racer view (docs/view.md): the access check, the JSON endpoints against a real store (a directory and S3) and a
real Redis, the workers publishing only while a page watches, and the page in headless Chromium against a real
``racer train --view``."""

from __future__ import annotations

import http.client
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest
import redis

from common.bus import Bus
from common.keys import Keys
from common.protocol import CarPose, PolicyVersion
from model_store import RunStore, open_store
from model_store.localize import localize_env
from racer.embedded_redis import EmbeddedRedis
from racer.evaluate import write_video
from racer.redis_record import remove_redis_record, write_redis_record
from racer.runconfig import build_run
from racer.view.data import METRIC_KEYS, video_name
from racer.view.server import ViewOptions, ViewServer
from rollout_worker.watch import WatchPublisher, encode_frame
from rollout_worker.worker import RolloutWorker, WorkerOptions
from sim.env import RacerEnv
from tests.conftest import S3_BUCKET
from trainer.evaluator import EvalSettings, evaluate_checkpoint, save_evaluation
from trainer.process import Trainer, TrainerOptions

RUN_ID = "view-run"
HP = {"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 2, "lr": 0.001, "discount_factor": 0.99}
ARTIFACTS = Path(os.environ.get("RACER_TEST_ARTIFACTS") or Path(__file__).parent / "artifacts")


def get(url: str, headers: dict | None = None) -> tuple[int, dict, bytes]:
    """(status, headers, body) of a GET, errors included."""
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers=headers or {}), timeout=20) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers), exc.read()


def get_json(url: str) -> object:
    status, _, body = get(url)
    assert status == 200, (url, status, body[:300])
    return json.loads(body)


def wait_for(check, timeout: float, what: str, every: float = 0.1):
    """``check()``'s first truthy value within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(every)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def base(server: ViewServer) -> str:
    return f"http://127.0.0.1:{server.port}"


def fill(trainer: Trainer, worker: RolloutWorker) -> None:
    for _ in range(60):
        worker.push(worker.collect())
        trainer.read(block_ms=100)
        if trainer.ready():
            return
    raise AssertionError("not enough episodes for an iteration")


@pytest.fixture(scope="module")
def stored(tmp_path_factory) -> Path:
    """A run in a directory store, made by the real trainer and worker: two iterations (metrics.jsonl), checkpoints
    v0-v2, an evaluation of v1 with a stored video, and of v2 without one."""
    root = tmp_path_factory.mktemp("view-store")
    (root / "hp.json").write_text(json.dumps(HP))
    store = str(root / "store")
    run, files = build_run(RUN_ID, hyperparams=str(root / "hp.json"))
    run = run.model_copy(update={"segment_steps": 16})
    with EmbeddedRedis() as server:
        trainer = Trainer(run, TrainerOptions(server.url, store, run_files=files))
        trainer.start()
        worker = RolloutWorker(WorkerOptions(RUN_ID, server.url, store, worker_index=0))
        worker.start()
        for _ in range(2):
            fill(trainer, worker)
            trainer.train()
            worker.poll_policy()
        worker.close()
    runs = RunStore(open_store(store))
    settings = EvalSettings(episodes=1)
    env_cfg = localize_env(run, runs, root)
    for version in (1, 2):
        save_evaluation(runs, evaluate_checkpoint(runs, run, env_cfg, version, settings))
    write_video(runs, run, env_cfg, 1, settings, path=root / "v1.mp4")
    runs.write_file(RUN_ID, video_name(1), (root / "v1.mp4").read_bytes())
    return Path(store)


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_the_endpoints_serve_the_stored_run(stored):
    runs = RunStore(open_store(str(stored)))
    with ViewServer(ViewOptions(RUN_ID, str(stored), port=0)) as server:
        url = base(server)
        run = get_json(f"{url}/api/run")
        assert run["run_id"] == RUN_ID and run["track"] == "racer_loop" and run["live"] is False
        assert run["action_space"]["sensors"] == ["FRONT_FACING_CAMERA"]
        rows = runs.read_metrics(RUN_ID)
        assert len(rows) == 2
        assert get_json(f"{url}/api/metrics") == [{k: r[k] for k in METRIC_KEYS if k in r} for r in rows]
        checkpoints = {c["version"]: c for c in get_json(f"{url}/api/checkpoints")}
        assert sorted(checkpoints) == [c["version"] for c in runs.list_checkpoints(RUN_ID)]
        best, latest = runs.pointer(RUN_ID, "best")["version"], runs.pointer(RUN_ID, "latest")["version"]
        assert [v for v, c in checkpoints.items() if c["best"]] == [best]
        assert [v for v, c in checkpoints.items() if c["latest"]] == [latest] == [2]
        assert [v for v, c in checkpoints.items() if c["evaluated"]] == [1, 2]
        assert [v for v, c in checkpoints.items() if c["video"]] == [1]
        evaluations = get_json(f"{url}/api/evaluations")
        assert [(e["version"], e["completion_rate"], e["best"]) for e in evaluations] == [
            (v, runs.read_evaluation(RUN_ID, v)["completion_rate"], v == best) for v in (1, 2)
        ]
        record = get_json(f"{url}/api/evaluation/1")
        assert record["trials"] == runs.read_evaluation(RUN_ID, 1)["trials"] and record["trials"][0]["trajectory"]
        status, _, body = get(f"{url}/api/evaluation/0")
        assert status == 404 and b"no evaluation" in body
        video = runs.read_file(RUN_ID, video_name(1))
        status, headers, body = get(f"{url}/api/video/1")
        assert status == 200 and body == video and headers["content-type"] == "video/mp4"
        status, headers, body = get(f"{url}/api/video/1", {"Range": "bytes=10-19"})
        assert status == 206 and body == video[10:20] and headers["content-range"] == f"bytes 10-19/{len(video)}"
        status, _, body = get(f"{url}/api/video/2")
        assert status == 404 and b"no video" in body
        track = get_json(f"{url}/api/track?name=racer_loop")
        assert track["closed"] and len(track["center"]) == len(track["inner"]) > 10
        assert get(f"{url}/api/track?name=..%2F..%2Fetc%2Fpasswd")[0] == 404
        assert get_json(f"{url}/api/live")["live"] is False
        status, _, page = get(f"{url}/")
        assert status == 200 and b"static/view.js" in page
        assert get(f"{url}/static/view.js")[0] == 200


def test_a_finished_run_from_an_s3_bucket(stored, s3_server):
    store = f"s3://{S3_BUCKET}/view"
    bucket = open_store(store, s3_server)
    for path in stored.rglob("*"):
        if path.is_file():
            bucket.put(path.relative_to(stored).as_posix(), path.read_bytes())
    with ViewServer(ViewOptions(RUN_ID, store, s3_endpoint=s3_server, port=0)) as server:
        metrics = get_json(f"{base(server)}/api/metrics")
        assert [m["mean_reward"] for m in metrics] == [r["mean_reward"] for r in RunStore(bucket).read_metrics(RUN_ID)]
        assert get(f"{base(server)}/api/video/1")[2] == (stored / "runs" / RUN_ID / video_name(1)).read_bytes()


def test_beyond_loopback_every_request_needs_the_token(stored):
    with ViewServer(ViewOptions(RUN_ID, str(stored), host="0.0.0.0", port=0)) as server:
        assert server.token and server.url.endswith(f"/?token={server.token}")
        url = base(server)
        for path in ("/", "/api/run", "/api/metrics", "/static/view.js", "/api/video/1"):
            assert get(f"{url}{path}")[0] == 403, path
            assert get(f"{url}{path}?token=wrong")[0] == 403, path
            assert get(f"{url}{path}", {"Cookie": "racer_view_token=wrong"})[0] == 403, path
        status, headers, _ = get(f"{url}/?token={server.token}")
        assert status == 200
        cookie = headers["set-cookie"].split(";")[0]
        assert cookie == f"racer_view_token={server.token}" and "HttpOnly" in headers["set-cookie"]
        assert get(f"{url}/api/metrics", {"Cookie": cookie})[0] == 200


def test_on_loopback_only_loopback_host_names_are_served(stored):
    with ViewServer(ViewOptions(RUN_ID, str(stored), port=0)) as server:
        assert server.token is None and server.url == f"http://127.0.0.1:{server.port}/"
        url = f"{base(server)}/api/run"
        assert get(url)[0] == 200
        assert get(url, {"Host": f"localhost:{server.port}"})[0] == 200
        # A page elsewhere that rebinds its own name to 127.0.0.1 sends its own name as the Host.
        assert get(url, {"Host": f"attacker.example:{server.port}"})[0] == 403


@pytest.mark.slow(reason="runs racer commands end to end")
def test_a_racer_eval_video_is_played_by_racer_view(tmp_path):
    """A new user's ``racer eval --video`` never reached the page: it is stored where racer view plays the
    checkpoint's video, so the checkpoint lists one and the server sends the very file, as video/mp4."""
    from typer.testing import CliRunner

    from common.action_space import ActionSpace
    from common.policy import action_space_spec, build_policy
    from common.weights import checkpoint_to_bytes
    from racer.cli import app

    store, run_id = tmp_path / "store", "eval-video"
    run, files = build_run(run_id)
    runs = RunStore(open_store(str(store)))
    for name, data in files.items():
        runs.write_file(run_id, name, data)
    runs.write_config(run)
    actions = ActionSpace.model_validate_json(files["model_metadata.json"])
    model = build_policy((120, 160, 1), action_space_spec(actions), run.policy)
    runs.save_checkpoint(run_id, 4, checkpoint_to_bytes(model.state_dict()), {"env_steps": 400})
    video = tmp_path / "lap.mp4"
    args = ["eval", "--run-id", run_id, "--store", str(store), "--checkpoint", "4", "--episodes", "1"]
    args += ["--one-direction", "--device", "cpu", "--video", str(video), "--json", "-"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout)
    assert record["video"]["view"] == runs.store.key_uri(f"runs/{run_id}/{video_name(4)}")
    assert "filmed trial 1/1 forward from 0: " in result.stderr
    assert f"stored {video} as {record['video']['view']}: racer view plays it as v4's video" in result.stderr
    with ViewServer(ViewOptions(run_id, str(store), port=0)) as server:
        checkpoints = get_json(f"{base(server)}/api/checkpoints")
        assert [(c["version"], c["video"]) for c in checkpoints] == [(4, True)]
        status, headers, body = get(f"{base(server)}/api/video/4")
        assert status == 200 and headers["content-type"] == "video/mp4" and body == video.read_bytes()
        status, headers, body = get(f"{base(server)}/api/video/4", {"Range": "bytes=0-7"})
        assert status == 206 and body == video.read_bytes()[:8] and body[4:8] == b"ftyp"  # an MP4's first box


def commands(client: redis.Redis) -> dict[str, int]:
    stats = client.info("commandstats")
    return {name.removeprefix("cmdstat_"): v["calls"] for name, v in stats.items()}


def test_a_worker_nobody_watches_publishes_nothing(run_id):
    """Unwatched: no pose or frame key, and one MGET a second at most; a page open: poses; a camera shown:
    frames too, each a JPEG of the 160×120 camera."""
    # A server of its own: the commands it counts are server-wide, and the session's server also carries whatever
    # an earlier test's processes are still winding down.
    server = EmbeddedRedis()
    client = redis.Redis.from_url(server.url)
    bus, keys = Bus(client, run_id), Keys(run_id)
    env = RacerEnv()
    publisher = WatchPublisher(bus, "w-0", 0, env.track.name)
    observation, info = env.reset(seed=1)

    def drive(seconds: float) -> int:
        nonlocal observation, info
        steps, end = 0, time.monotonic() + seconds
        while time.monotonic() < end:
            observation, _, term, trunc, info = env.step(env.action_space.sample())
            publisher.step(observation, info)
            steps += 1
            if term or trunc:
                observation, info = env.reset()
        return steps

    client.config_resetstat()
    steps = drive(1.5)
    used = commands(client)
    assert steps > 100 and not list(client.scan_iter(match=f"{keys.base}:*"))
    assert used.get("mget", 0) <= 2 and not used.get("set") and not used.get("get"), used
    bus.watch([])  # a page is open, showing no camera
    drive(1.2)
    pose = CarPose.from_json(client.get(keys.pose("w-0")))
    assert pose.track == "racer_loop" and pose.frames == 0 and client.get(keys.frame("w-0")) is None
    assert 0 < client.ttl(keys.pose("w-0")) <= 3
    client.config_resetstat()
    bus.watch(["w-0"])
    drive(2.2)
    sets = commands(client).get("set", 0)
    assert sets <= 2 + 2.2 * 15 * 2, sets  # pose and frame, ≤ 15 a second (plus the watch marks)
    frame = cv2.imdecode(np.frombuffer(client.get(keys.frame("w-0")), np.uint8), cv2.IMREAD_UNCHANGED)
    assert frame.shape == (120, 160)
    assert CarPose.from_json(client.get(keys.pose("w-0"))).frames >= 10
    env.close()
    server.stop()


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_a_redis_outage_never_stops_the_worker_s_steps(run_id):
    server = EmbeddedRedis()
    bus = Bus(redis.Redis.from_url(server.url), run_id)
    env = RacerEnv()
    observation, info = env.reset(seed=2)
    publisher = WatchPublisher(bus, "w-0", 0, env.track.name)
    bus.watch(["w-0"])
    wait_for(lambda: publisher.step(observation, info) or publisher.camera, 5, "the publisher to see the page")
    publisher.step(observation, info)
    assert bus.frame("w-0") is not None or wait_for(lambda: bus.frame("w-0"), 2, "a frame")
    server.stop()
    end = time.monotonic() + 2.5  # two checks fail: each is one warning at most, never an exception
    while time.monotonic() < end:
        publisher.step(observation, info)
    assert not publisher.watched and not publisher.camera
    publisher.close()
    env.close()


def test_a_stereo_frame_shows_both_images_side_by_side():
    left, right = np.full((120, 160), 30, np.uint8), np.full((120, 160), 220, np.uint8)
    frame = cv2.imdecode(np.frombuffer(encode_frame(np.dstack([left, right])), np.uint8), cv2.IMREAD_UNCHANGED)
    assert frame.shape == (120, 320)
    assert abs(int(frame[:, :160].mean()) - 30) < 3 and abs(int(frame[:, 160:].mean()) - 220) < 3


def mjpeg_frames(port: int, worker: str, count: int, timeout: float = 20) -> list[bytes]:
    """The first ``count`` JPEGs of the camera stream of ``worker``."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    conn.request("GET", f"/api/camera?worker={worker}")
    response = conn.getresponse()
    assert response.status == 200 and "multipart/x-mixed-replace" in response.getheader("content-type")
    frames, buffer = [], b""
    while len(frames) < count:
        buffer += response.read1(65536)
        m = re.search(rb"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: (\d+)\r\n\r\n", buffer)
        if m and len(buffer) >= m.end() + int(m.group(1)):
            frames.append(buffer[m.end() : m.end() + int(m.group(1))])
            buffer = buffer[m.end() + int(m.group(1)) :]
    conn.close()
    return frames


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_live_poses_and_camera_from_a_real_worker(stored, redis_url, tmp_path):
    """A real worker acting with the stored policy: the page's poll makes it publish; its pose reaches /api/live,
    its frames /api/frame and two camera streams at once."""
    store = tmp_path / "store"
    shutil.copytree(stored, store)
    bus = Bus(redis.Redis.from_url(redis_url), RUN_ID)
    bus.publish_policy(PolicyVersion(version=2, checkpoint_key="", created=time.time()))
    worker = RolloutWorker(WorkerOptions(RUN_ID, redis_url, str(store), worker_index=1, worker_id="w-1"))
    worker.start()
    with ViewServer(ViewOptions(RUN_ID, str(store), redis_url=redis_url, port=0)) as server:
        url = base(server)
        assert get_json(f"{url}/api/run")["live"] is True
        worker.collect()
        assert not bus.poses()[0], "nobody watched yet"
        assert get_json(f"{url}/api/live")["poses"] == []
        wait_for(lambda: bus.redis.exists(bus.keys.watchers), 5, "the watchers mark")
        time.sleep(1.0)  # the worker looks again after a second
        worker.collect()

        def posed():
            poses = get_json(f"{url}/api/live")["poses"]
            return poses if poses else None

        (pose,) = wait_for(posed, 5, "the worker's pose on /api/live")
        assert pose["worker_id"] == "w-1" and pose["index"] == 1 and pose["track"] == "racer_loop"
        assert get(f"{url}/api/frame?worker=w-1")[0] == 404  # asked for: the worker sends frames from now on
        assert get(f"{url}/api/frame?worker=w*")[0] == 404
        wait_for(lambda: bus.redis.exists(bus.keys.camera_watch("w-1")), 5, "the camera mark")
        time.sleep(1.0)
        worker.collect()

        def framed():
            status, headers, body = get(f"{url}/api/frame?worker=w-1")
            return body if status == 200 and headers["content-type"] == "image/jpeg" else None

        jpeg = wait_for(framed, 5, "a frame on /api/frame")
        assert cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_UNCHANGED).shape == (120, 160)
        # Two pages at once each get the camera stream.
        import threading

        results: list[list[bytes]] = []
        readers = [threading.Thread(target=lambda: results.append(mjpeg_frames(server.port, "w-1", 2))) for _ in "ab"]
        for t in readers:
            t.start()
        end = time.monotonic() + 15
        while any(t.is_alive() for t in readers) and time.monotonic() < end:
            worker.collect()
        for t in readers:
            t.join(timeout=5)
        assert len(results) == 2 and all(len(r) == 2 and r[0] != r[1] for r in results)
        # A worker that stops stepping (it waits out a PPO update) keeps its car on the page while it beats.
        worker.beat()
        wait_for(lambda: not bus.poses()[0], 6, "the pose key to expire")
        (pose,) = get_json(f"{url}/api/live")["poses"]
        assert pose["worker_id"] == "w-1"
        bus.redis.delete(bus.keys.heartbeat("w-1"))
        wait_for(lambda: not get_json(f"{url}/api/live")["poses"], 5, "the car to leave once its heartbeat is gone")
    worker.close()


def test_the_redis_racer_train_recorded_is_used_while_it_answers(stored, redis_url, tmp_path):
    store = tmp_path / "store"
    shutil.copytree(stored, store)
    record = write_redis_record(str(store), RUN_ID, redis_url)  # as racer train records it, with this live pid
    with ViewServer(ViewOptions(RUN_ID, str(store), port=0)) as server:
        assert server.redis_url == redis_url and get_json(f"{base(server)}/api/live")["live"] is True
    write_redis_record(str(store), RUN_ID, "redis://127.0.0.1:1/0")  # a launcher whose Redis no longer answers
    with ViewServer(ViewOptions(RUN_ID, str(store), port=0)) as server:
        assert server.live is None and "does not answer" in server.note
        assert get_json(f"{base(server)}/api/metrics")
    remove_redis_record(record)
    with ViewServer(ViewOptions(RUN_ID, str(store), port=0)) as server:  # the run has ended: the store alone
        assert server.live is None and get_json(f"{base(server)}/api/metrics")


def test_racer_view_serves_until_stopped(stored):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent.parent), *sys.path])}
    cmd = [sys.executable, "-m", "racer", "view", "--run-id", RUN_ID, "--store", str(stored), "--port", "0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        lines = [proc.stdout.readline(), proc.stdout.readline()]
        assert "the run as stored" in lines[0], lines
        url = re.search(r"racer view: (http://127\.0\.0\.1:\d+/)", lines[1]).group(1)
        assert get_json(f"{url}api/run")["run_id"] == RUN_ID
    finally:
        proc.send_signal(signal.SIGTERM)
        out = proc.communicate(timeout=30)[0]
    assert proc.returncode == 0, out


def test_racer_view_refuses_bad_input_in_one_line(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent.parent), *sys.path])}
    for args, expected in (
        (["--run-id", "nosuch", "--store", str(tmp_path), "--port", "0"], "run 'nosuch' does not exist"),
        (["--run-id", "a/b", "--store", str(tmp_path)], "invalid run id 'a/b'"),
    ):
        proc = subprocess.run(
            [sys.executable, "-m", "racer", "view", *args], capture_output=True, text=True, timeout=60, env=env
        )
        assert proc.returncode == 2 and expected in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, (
            proc.stderr
        )


# --- the page in a real browser ---------------------------------------------------------------------------------------
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")


def browser():
    """Headless Chromium (Debian's package) through its matching chromedriver."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1400,2000"):
        options.add_argument(arg)
    return webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)


def shown_cars(driver) -> dict[str, tuple[float, float]]:
    """The workers' table as the page shows it now (read in one script: the page redraws it 5 times a second)."""
    rows = driver.execute_script(
        "return Array.from(document.querySelectorAll('#workers tbody tr')).map((r) => "
        "[r.dataset.worker, r.querySelector('.x').dataset.value, r.querySelector('.y').dataset.value])"
    )
    return {w: (float(x), float(y)) for w, x, y in rows}


def shown_value(driver, key: str) -> tuple[str, str | None, str | None]:
    """(text, data-value, data-x) of a chart's last value as the page shows it."""
    return tuple(
        driver.execute_script(
            "const el = document.querySelector(`.last[data-key='${arguments[0]}']`);"
            "return el ? [el.textContent, el.dataset.value ?? null, el.dataset.x ?? null] : ['', null, null];",
            key,
        )
    )


NEEDS_CHROMIUM = pytest.mark.skipif(
    not (CHROMIUM and CHROMEDRIVER), reason="needs Debian's chromium and chromium-driver (.ci/run installs them)"
)


@pytest.mark.slow(reason="drives a real headless browser")
@NEEDS_CHROMIUM
def test_a_finished_run_in_headless_chromium(stored):
    """The page of a stored run, no Redis: charts equal to metrics.jsonl, the checkpoint list with its pointers,
    the stored video of v1 playing, and v2's missing video said."""
    pytest.importorskip("selenium", reason="needs selenium (the dev extras)")
    runs = RunStore(open_store(str(stored)))
    with ViewServer(ViewOptions(RUN_ID, str(stored), port=0)) as server:
        driver = browser()
        try:
            driver.get(server.url)
            wait_for(lambda: shown_value(driver, "mean_reward")[1] is not None, 30, "the charts", 0.3)
            last = runs.read_metrics(RUN_ID)[-1]
            for key in ("mean_reward", "mean_progress", "entropy", "approx_kl", "steps_per_s"):
                text, value, x = shown_value(driver, key)
                assert int(x) == last["iteration"] and float(value) == last[key], (key, value, last[key])
            assert "finished run" in driver.find_element("id", "status").text
            pointers = driver.execute_script(
                "return Array.from(document.querySelectorAll('#checkpoints tbody tr')).map((r) => "
                "[Number(r.dataset.version), r.querySelector('.pointers').textContent])"
            )
            best = runs.pointer(RUN_ID, "best")["version"]
            assert {v: p for v, p in pointers} == {
                v: ("best" if v == best else "") + ("latest" if v == 2 else "") for v in (0, 1, 2)
            }
            wait_for(lambda: driver.find_elements("id", "video-none"), 10, "v2's missing video said")
            driver.execute_script("document.querySelector('#checkpoints tr[data-version=\"1\"]').click()")
            playable = wait_for(
                lambda: driver.execute_script(
                    "const v = document.getElementById('video');"
                    "return v && v.readyState >= 1 && v.duration > 0 ? v.duration : null"
                ),
                20,
                "v1's video loaded in the page",
            )
            assert playable > 0.1
            ARTIFACTS.mkdir(parents=True, exist_ok=True)
            assert driver.save_screenshot(str(ARTIFACTS / "view-finished.png"))
        finally:
            driver.quit()


@pytest.mark.slow("a real racer train with two workers and the evaluator, watched from Chromium: ~2 min")
@NEEDS_CHROMIUM
def test_the_page_in_headless_chromium_follows_a_real_run(tmp_path, redis_url):
    pytest.importorskip("selenium", reason="needs selenium (the dev extras)")
    (tmp_path / "hp.json").write_text(json.dumps(HP))
    run_id = "view-e2e"
    cmd = [sys.executable, "-m", "racer", "train", "--workers", "2", "--run-id", run_id, "--hyperparams", "hp.json"]
    cmd += ["--time-limit", "240s", "--redis", redis_url, "--eval-episodes", "1", "--view", "--view-port", "0"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    driver = None
    try:
        line = wait_for(lambda: proc.stdout.readline(), 60, "racer train's first line")
        while "racer view:" not in line:
            line = proc.stdout.readline()
            assert line, "racer train ended before printing the view's URL"
        url = re.search(r"(http://\S+)", line).group(1)
        driver = browser()
        driver.get(url)
        runs = RunStore(open_store(str(tmp_path)))
        # ≥ 2 cars, each seen in two places.
        first = wait_for(lambda: (c := shown_cars(driver)) and len(c) >= 2 and c, 120, "two cars on the page", 0.5)

        # Both cars moving: a worker may be waiting out a PPO update when first seen, so wait for each to move.
        def moved() -> list[str]:
            shown = shown_cars(driver) or {}
            return [w for w in first if w in shown and shown[w] != first[w]]

        wait_for(lambda: len(moved()) >= 2, 90, f"both cars moving (first seen at {first})")
        # The camera of the first worker: an MJPEG image of 160×120 in the page.
        wait_for(
            lambda: driver.execute_script("return document.getElementById('camera').naturalWidth") == 160,
            30,
            "a camera frame",
        )
        # The charts show the store's values: wait for an evaluation (it comes after an iteration).
        wait_for(lambda: shown_value(driver, "completion")[1] is not None, 150, "an evaluation on the page", 1.0)
        time.sleep(3.5)  # one more store poll, so metrics and evaluations are read after each other
        rows = {r["iteration"]: r for r in runs.read_metrics(run_id)}
        for key in ("mean_reward", "mean_progress", "entropy", "approx_kl", "policy_loss", "value_loss", "steps_per_s"):
            text, value, x = shown_value(driver, key)
            stored = rows[int(x)][key]
            assert float(value) == stored, (key, value, stored)
            assert float(text) == pytest.approx(stored, rel=1e-3, abs=1e-9), (key, text, stored)
        text, value, x = shown_value(driver, "completion")
        evaluation = runs.read_evaluation(run_id, int(x))
        assert float(value) == 100 * evaluation["completion_rate"]
        shown_versions = driver.execute_script(
            "return Array.from(document.querySelectorAll('#checkpoints tbody tr'))"
            ".map((r) => Number(r.dataset.version))"
        )
        listed = [c["version"] for c in runs.list_checkpoints(run_id)]
        assert shown_versions and set(shown_versions) <= set(range(max(listed) + 2)), (shown_versions, listed)
        trials = driver.execute_script("return document.querySelectorAll('#trials tbody tr').length")
        assert trials == evaluation["episodes"] == 2

        def best_shown_is_the_stores() -> bool:
            """The page's best badge against the store's best: the page polls the store, so ``best`` may move (it
            moved 1 → 3 between a poll and this check in one CI run) and the page follows within a poll."""
            best_before = runs.pointer(run_id, "best")["version"]
            shown_best = driver.execute_script(
                "return Array.from(document.querySelectorAll('#checkpoints tbody tr'))"
                ".filter((r) => r.querySelector('.badge.best')).map((r) => Number(r.dataset.version))"
            )
            return shown_best in ([best_before], [runs.pointer(run_id, "best")["version"]])

        wait_for(best_shown_is_the_stores, 10, "the page's best checkpoint to be the store's", 0.5)
        # The last evaluation's laps are drawn: coloured pixels on the track canvas.
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        assert driver.save_screenshot(str(ARTIFACTS / "view.png"))
        # A second browser at once sees the same cars.
        second = browser()
        try:
            second.get(url)
            wait_for(lambda: len(shown_cars(second)) >= 2, 30, "the cars in a second browser", 0.5)
        finally:
            second.quit()
    finally:
        if driver is not None:
            driver.quit()
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        out = proc.communicate(timeout=120)[0]
    assert proc.returncode == 0, out
