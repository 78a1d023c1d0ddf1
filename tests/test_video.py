"""sim.video: an evaluation episode recorded as an H.264 MP4 (what browsers play) that OpenCV decodes back frame by
frame, and the MPEG-4 part 2 fallback where no H.264 encoder is installed."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from sim.env import RacerEnv
from sim.physics import Pose
from sim.texture import TextureFrame, draw_surface
from sim.track import load_track
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
    env = RacerEnv(track="reinvent_base")
    yield env
    env.close()


def test_record_episode_writes_a_decodable_mp4(env, tmp_path):
    path = tmp_path / "videos" / "episode.mp4"
    # Waypoint 0 of reinvent_base starts a long straight: 30 straight steps (2 s at 1 m/s) stay on the road.
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


def test_a_tall_track_is_shrunk_to_the_camera_height(tmp_path):
    track = load_track("H_track")  # taller than wide: the 480-wide top-down view would be ~630 px tall
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
