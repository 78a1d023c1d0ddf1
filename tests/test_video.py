"""sim.video: an evaluation episode recorded as an H.264 MP4 (what browsers play) that OpenCV decodes back frame by
frame, and the MPEG-4 part 2 fallback where no H.264 encoder is installed."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from common.defaults import DEFAULT_TRACK
from sim.env import RacerEnv
from sim.physics import Pose
from sim.texture import TextureFrame, draw_surface
from sim.track import Track
from sim.track_gen import racer_track_array
from sim.video import EpisodeVideo, record_episode

STRAIGHT = 5  # DeepRacer's default action space: 0° at 1 m/s
STEPS = 30


def read_video(path: Path) -> tuple[list[np.ndarray], float]:
    """Every frame of a video (BGR) and the frame rate it declares."""
    cap = cv2.VideoCapture(str(path))
    assert cap.isOpened(), f"{path} does not open"
    fps = cap.get(cv2.CAP_PROP_FPS)
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    return frames, fps


@pytest.fixture(scope="module")
def env():
    env = RacerEnv(track=DEFAULT_TRACK)
    yield env
    env.close()


def test_record_episode_writes_a_decodable_mp4(env, tmp_path):
    path = tmp_path / "videos" / "episode.mp4"
    # Waypoint 0 of racer_loop is on its straightest stretch: 30 straight steps (2 s at 1 m/s) stay on the road.
    summary = record_episode(env, lambda obs: STRAIGHT, path, max_steps=STEPS, options={"start_index": 0})
    assert summary["steps"] == STEPS
    assert summary["frames"] == STEPS + 1  # the reset frame, then one per step
    assert summary["status"] == "in_progress"
    assert 0 < summary["progress"] < 100
    frames, fps = read_video(path)
    assert abs(len(frames) - summary["frames"]) <= 1
    assert fps == pytest.approx(15)
    assert frames[0].shape == (360, 960, 3)  # camera 480×360 beside a 480-wide top-down view, padded to 360
    assert all(f.shape == frames[0].shape for f in frames)
    assert min(float(f.std()) for f in frames) > 10
    # The car moves: the camera sees the dashes of the centre line go by and the car moves on the map.
    diffs = [np.abs(a.astype(int) - b.astype(int)).mean() for a, b in zip(frames[2:], frames[3:], strict=False)]
    assert min(diffs) > 0.5
    camera, top = frames[-1][:, :480].astype(int), frames[-1][:, 480:].astype(int)
    assert np.abs(camera - frames[0][:, :480]).mean() > 5
    assert np.abs(top - frames[0][:, 480:]).mean() > 0.1


def test_episode_video_sizes_are_even_and_frames_are_counted(env, tmp_path):
    obs, _ = env.reset(seed=1)
    with EpisodeVideo(tmp_path / "v.mp4", env.track, env.texture, env.frame, top_width=301) as video:
        video.add(obs, env.physics.pose)
        video.add(obs[..., 0], Pose(env.physics.pose.x + 0.3, env.physics.pose.y, 0.0), text="moved")
        assert video.frames == 2
        width, height = video.size
        assert width % 2 == 0 and height % 2 == 0
    frames, _ = read_video(tmp_path / "v.mp4")
    assert len(frames) == 2 and frames[0].shape == (height, width, 3)
    with pytest.raises(RuntimeError, match="closed"):
        video.add(obs, env.physics.pose)


def test_episode_video_refuses_a_wrong_camera_image(env, tmp_path):
    video = EpisodeVideo(tmp_path / "v.mp4", env.track, env.texture, env.frame)
    with video, pytest.raises(ValueError, match="120, 160"):
        video.add(np.zeros((60, 80), np.uint8), env.physics.pose)
    assert video.frames == 0


def tall_track() -> Track:
    """racer_loop turned a quarter turn anticlockwise (x, y -> -y, x; still a counter-clockwise loop): its borders
    span 4.17 m across and 8.06 m up."""
    rows = racer_track_array(DEFAULT_TRACK)
    turned = rows.copy()
    turned[:, 0::2] = rows[:, 1::2].max() + 0.5 - rows[:, 1::2]
    turned[:, 1::2] = rows[:, 0::2]
    return Track.from_array(turned, name="racer_loop_turned")


def test_a_tall_track_is_shrunk_to_the_camera_height(tmp_path):
    # Taller than wide: with the texture's 1.5 m margins, 7.17 m by 11.06 m, so the 480-wide top-down view would be
    # 480 x 11.06 / 7.17 = 741 px tall, and is shrunk to 360 px, 233 px wide.
    track = tall_track()
    frame = TextureFrame.for_track(track, ppm=40)
    texture = draw_surface(track, frame)
    camera = np.full((120, 160), 128, np.uint8)
    pose = Pose(*track.center[0], 0.0)
    with EpisodeVideo(tmp_path / "tall.mp4", track, texture, frame) as video:
        picture = video.compose(camera, pose)
        video.add(camera, pose)
    assert picture.shape == (360, video.size[0], 3)
    assert video.size[0] < 960 and video.size[0] % 2 == 0
    frames, _ = read_video(tmp_path / "tall.mp4")
    assert len(frames) == 1 and frames[0].shape == picture.shape


def test_the_video_is_h264_in_yuv420p_with_its_index_first(env, tmp_path):
    """Browsers play H.264 in yuv420p; +faststart puts the MP4 index first so a browser starts before the end."""
    import av

    path = tmp_path / "h264.mp4"
    summary = record_episode(env, lambda obs: STRAIGHT, path, max_steps=5, options={"start_index": 0})
    assert summary["fourcc"] == "avc1"
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264" and stream.codec_context.pix_fmt == "yuv420p"
        assert sum(1 for _ in container.decode(stream)) == summary["frames"]
    head = path.read_bytes()[:4096]
    assert head.find(b"moov") != -1 and (head.find(b"mdat") == -1 or head.find(b"moov") < head.find(b"mdat"))


def test_without_an_h264_encoder_it_writes_mp4v_and_says_so(env, tmp_path, monkeypatch, caplog):
    import sim.video

    monkeypatch.setattr(sim.video, "h264_available", lambda: False)  # a machine without PyAV's libx264
    path = tmp_path / "fallback.mp4"
    with caplog.at_level("WARNING", logger="sim.video"):
        summary = record_episode(env, lambda obs: STRAIGHT, path, max_steps=5, options={"start_index": 0})
    assert summary["fourcc"] == "mp4v"
    assert "no H.264 encoder here" in caplog.text and "browsers do not" in caplog.text
    frames, _ = read_video(path)
    assert abs(len(frames) - summary["frames"]) <= 1


# --- object avoidance, head-to-bot, stereo cameras and LiDAR in the video ------------------------------------------


def _oa_env(sensors: list[str] | None, tmp_path: Path, **race) -> RacerEnv:
    from common.race import RaceConfig

    kwargs = {}
    if sensors:
        space = tmp_path / "model_metadata.json"
        space.write_text(
            '{"action_space": [{"steering_angle": 0, "speed": 1.0}], "action_space_type": "discrete", '
            f'"sensor": {json.dumps(sensors)}, "version": "5"}}'
        )
        kwargs["action_space"] = str(space)
    return RacerEnv(track=DEFAULT_TRACK, race=RaceConfig(**race), **kwargs)


def _top_pixel(video: EpisodeVideo, x: float, y: float) -> tuple[int, int]:
    """(row, column) in a composed frame of the world point (x, y) on the top-down panel (racer_loop: wider than
    tall, so the panel is not shrunk, only padded to the camera's height)."""
    u, v = np.round(video._frame.to_pixels(np.array([[x, y]]))).astype(int)[0]
    pad = (video.height - video._frame.height) // 2
    return int(v) + pad, 160 * 3 + int(u)


def test_the_top_down_panel_shows_the_boxes_where_they_are(tmp_path):
    from sim.views import BOX_COLOR

    env = _oa_env(None, tmp_path, race_type="OBJECT_AVOIDANCE", object_avoidance={"number_of_obstacles": 3})
    try:
        obs, _ = env.reset(seed=3)
        with EpisodeVideo(tmp_path / "oa.mp4", env.track, env.texture, env.frame) as video:
            plain = video.compose(obs, env.physics.pose)
            picture = video.compose(obs, env.physics.pose, objects=env.objects)
        assert len(env.objects) == 3
        for o in env.objects:
            r, c = _top_pixel(video, o.x, o.y)
            assert (picture[r - 1 : r + 2, c - 1 : c + 2] == BOX_COLOR).all()
            assert not (plain[r - 1 : r + 2, c - 1 : c + 2] == BOX_COLOR).all(axis=2).any()
        assert np.array_equal(picture[:, :480], plain[:, :480])  # the camera panel is the same
    finally:
        env.close()


def test_a_head_to_bot_episode_records_its_moving_bots(tmp_path):
    from sim.views import BOT_COLOR

    env = _oa_env(None, tmp_path, race_type="HEAD_TO_BOT", head_to_bot={"number_of_bot_cars": 2, "bot_car_speed": 0.5})
    try:
        path = tmp_path / "h2b.mp4"
        summary = record_episode(env, lambda obs: STRAIGHT, path, max_steps=8, seed=0)
        frames, _ = read_video(path)
        assert abs(len(frames) - summary["frames"]) <= 1
        # The last frame shows the bots where the env has them now (blue, within the codec's error).
        last = cv2.cvtColor(frames[-1], cv2.COLOR_BGR2RGB).astype(int)
        with EpisodeVideo(tmp_path / "x.mp4", env.track, env.texture, env.frame) as video:
            for o in env.objects:
                r, c = _top_pixel(video, o.x - 0.08 * np.cos(o.yaw), o.y - 0.08 * np.sin(o.yaw))
                assert np.abs(last[r, c] - BOT_COLOR).max() < 60
    finally:
        env.close()


def test_a_stereo_frame_shows_both_images_and_the_lidar_plot(tmp_path):
    env = _oa_env(
        ["STEREO_CAMERAS", "LIDAR"], tmp_path, race_type="OBJECT_AVOIDANCE", object_avoidance={"number_of_obstacles": 2}
    )
    try:
        obs, _ = env.reset(seed=0)
        assert obs["camera"].shape == (120, 160, 2)
        with EpisodeVideo(tmp_path / "s.mp4", env.track, env.texture, env.frame) as video:
            picture = video.compose(obs["camera"], env.physics.pose, objects=env.objects)
            with_lidar = video.compose(obs["camera"], env.physics.pose, objects=env.objects, lidar=obs["lidar"])
            right_only = obs["camera"].copy()
            right_only[..., 0] = 0
            no_left = video.compose(right_only, env.physics.pose)
        assert picture.shape == (360, 960, 3)  # the panel keeps its size
        # Left image on the left half of the panel at ×1.5 (180 rows, centred), right image on the right half.
        left, right = picture[90:270, :240], picture[90:270, 240:480]
        assert left.std() > 10 and right.std() > 10
        assert no_left[100:230, 10:230].mean() < 5  # the left image blanked shows black on the left
        assert no_left[100:230, 250:470].mean() > 20
        # The LiDAR plot darkens and draws into the camera panel's bottom-right corner only.
        changed = (with_lidar != picture).any(axis=2)
        rows, cols = np.nonzero(changed)
        assert changed.sum() > 100 and rows.min() >= 270 and cols.min() >= 390 and cols.max() < 480
        # A whole episode with the dict observation goes through record_episode.
        summary = record_episode(env, lambda o: 0, tmp_path / "rec.mp4", max_steps=3, seed=1)
        assert summary["frames"] == summary["steps"] + 1
    finally:
        env.close()


def test_a_sector_lidar_plot_and_a_bad_lidar(env, tmp_path):
    obs, _ = env.reset(seed=1)
    with EpisodeVideo(tmp_path / "sector.mp4", env.track, env.texture, env.frame) as video:
        none = video.compose(obs, env.physics.pose, lidar=np.zeros(8, np.float32))
        some = video.compose(obs, env.physics.pose, lidar=np.array([1, 0, 0, 0, 0, 0, 0, 0], np.float32))
        assert (np.abs(some.astype(int) - none.astype(int)).sum(axis=2) > 100).sum() > 50  # one red wedge
        with pytest.raises(ValueError, match="LIDAR"):
            video.compose(obs, env.physics.pose, lidar=np.zeros(5, np.float32))
