"""What ``racer view`` reads from the store: the run, its metrics, checkpoints, evaluations, videos and tracks.

Everything goes through ``model_store.runs.RunStore`` (a directory or a bucket alike) and is JSON only. Several
browsers poll the same figures every few seconds, so reads are cached for ``ttl_s`` (an evaluation record, written
once, for good).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.config import RunConfig
from model_store.runs import RunStore, run_prefix
from model_store.store import StoreError, StoreKeyError
from sim.track import Track, TrackError, known_track_names, load_track

CACHE_TTL_S = 2.0
"""How long a figure read from the store is served again before it is read anew."""
VIDEOS_DIR = "videos"
"""The run folder of evaluation videos the page plays: ``videos/{version:09d}.mp4``."""
METRIC_KEYS: tuple[str, ...] = (
    "iteration",
    "policy_version",
    "env_steps",
    "episodes",
    "mean_reward",
    "mean_progress",
    "laps_completed",
    "mean_lap_time_s",
    "steps_per_s",
    "entropy",
    "approx_kl",
    "policy_loss",
    "value_loss",
    "clip_fraction",
    "learning_rate",
    "train_s",
    "time",
)
"""The columns of metrics.jsonl the page charts or shows (the store's values, unchanged)."""
CHECKPOINT_KEYS: tuple[str, ...] = (
    "version",
    "env_steps",
    "episodes",
    "iteration",
    "created",
    "size_bytes",
    "latest",
    "best",
    "rolled_back_to",
)
"""The checkpoint metadata the page lists (not the run config every checkpoint carries)."""
SUMMARY_KEYS: tuple[str, ...] = (
    "version",
    "env_steps",
    "track",
    "episodes",
    "completion_rate",
    "mean_progress",
    "best_lap_s",
    "mean_lap_s",
    "off_track",
    "crashed",
    "score",
    "created",
)
"""The figures of an evaluation record the page shows for each evaluation."""


def video_name(version: int) -> str:
    """Run file name of checkpoint ``version``'s evaluation video: ``videos/{version:09d}.mp4``."""
    return f"{VIDEOS_DIR}/{int(version):09d}.mp4"


def _pick(d: dict[str, Any], keys: tuple[str, ...]) -> dict[str, Any]:
    return {k: d[k] for k in keys if k in d}


class RunData:
    """One run's stored figures, read through ``runs`` and cached for several pages."""

    def __init__(
        self, runs: RunStore, run_id: str, config: RunConfig | None = None, ttl_s: float = CACHE_TTL_S
    ) -> None:
        """``config``: the run's, when the caller has it (``racer train --view``, before the trainer has stored it);
        otherwise read from the store now: StoreKeyError naming the run if it does not exist."""
        self.runs, self.run_id, self.ttl_s = runs, run_id, ttl_s
        self.config: RunConfig = config or runs.read_config(run_id)
        self._lock = threading.Lock()
        self._cache: dict[str, tuple[float, Any]] = {}
        self._evaluations: dict[int, dict[str, Any]] = {}
        self._tracks: dict[str, Track] = {}

    def _cached(self, name: str, read: Callable[[], Any]) -> Any:
        now = time.monotonic()
        with self._lock:
            hit = self._cache.get(name)
            if hit is not None and now - hit[0] < self.ttl_s:
                return hit[1]
        value = read()
        with self._lock:
            self._cache[name] = (now, value)
        return value

    # -- the run -----------------------------------------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        """The run as the page introduces it: id, store, track, each worker's track, sensors and action space."""
        env = self.config.env
        tracks = [self._track_name(t) for t in self._config_tracks()]
        return {
            "run_id": self.run_id,
            "store": self.runs.store.key_uri(run_prefix(self.run_id)),
            "track": tracks[0],
            "tracks": sorted(set(tracks)),
            "worker_tracks": [self._track_name(w.apply(env).track) for w in self.config.worker_envs],
            "race_type": env.race.race_type.value,
            "action_space": self._action_space(),
        }

    def _action_space(self) -> dict[str, Any] | None:
        try:
            meta = self.runs.read_file(self.run_id, "model_metadata.json")
        except StoreKeyError:
            return None
        from common.action_space import ActionSpace

        space = ActionSpace.model_validate_json(meta)
        return {"discrete": space.discrete, "sensors": list(space.sensor)}

    # -- training --------------------------------------------------------------------------------------------------
    def metrics(self) -> list[dict[str, Any]]:
        """One row per training iteration (metrics.jsonl), the charted columns only."""
        return self._cached(
            "metrics", lambda: [_pick(r, METRIC_KEYS) for r in self.runs.read_metrics(self.run_id, True)]
        )

    def checkpoints(self) -> list[dict[str, Any]]:
        """Each whole checkpoint with its ``best``/``latest`` flags, whether it was evaluated and has a video."""
        return self._cached("checkpoints", self._read_checkpoints)

    def _read_checkpoints(self) -> list[dict[str, Any]]:
        evaluated = set(self.evaluation_versions())
        videos = self._video_versions()
        return [
            {**_pick(c, CHECKPOINT_KEYS), "evaluated": c["version"] in evaluated, "video": c["version"] in videos}
            for c in self.runs.list_checkpoints(self.run_id)
        ]

    def _video_versions(self) -> set[int]:
        prefix = f"{run_prefix(self.run_id)}{VIDEOS_DIR}/"
        names = (info.key[len(prefix) :] for info in self.runs.store.list(prefix))
        return {int(n[:9]) for n in names if len(n) == 13 and n[:9].isdigit() and n.endswith(".mp4")}

    # -- evaluations -----------------------------------------------------------------------------------------------
    def evaluation_versions(self) -> list[int]:
        """Evaluated checkpoint versions, ascending."""
        return self._cached("evaluation_versions", lambda: self.runs.evaluation_versions(self.run_id))

    def evaluation(self, version: int) -> dict[str, Any]:
        """The whole evaluation record of ``version`` (trials with trajectories); StoreKeyError if there is none.
        Cached for good: the evaluator writes each record once."""
        with self._lock:
            hit = self._evaluations.get(version)
        if hit is None:
            hit = {**self.runs.read_evaluation(self.run_id, version), "version": version}
            with self._lock:
                self._evaluations[version] = hit
        return hit

    def evaluations(self) -> list[dict[str, Any]]:
        """Each evaluation's figures, version order (an unreadable record is left out)."""
        return self._cached("evaluations", self._read_evaluations)

    def _read_evaluations(self) -> list[dict[str, Any]]:
        out = []
        best = (self.runs.pointer(self.run_id, "best") or {}).get("version")
        for version in self.evaluation_versions():
            try:
                record = self.evaluation(version)
            except StoreError:  # malformed, or deleted since the listing
                continue
            out.append({**_pick(record, SUMMARY_KEYS), "version": version, "best": version == best})
        return out

    def video(self, version: int) -> bytes | None:
        """The stored MP4 of ``version``'s evaluation, or None if the store has none."""
        try:
            return self.runs.read_file(self.run_id, video_name(version))
        except StoreKeyError:
            return None

    # -- tracks ----------------------------------------------------------------------------------------------------
    def _config_tracks(self) -> list[str]:
        """The run's track first, then each worker world's (names or paths, as config.json holds them)."""
        env = self.config.env
        return [env.track, *(w.apply(env).track for w in self.config.worker_envs)]

    def _config_track(self, spec: str) -> Track:
        with self._lock:
            track = self._tracks.get(spec)
        if track is None:
            track = load_track(spec)
            with self._lock:
                self._tracks[spec] = track
        return track

    def _track_name(self, spec: str) -> str:
        """The name poses and trials carry for a track of config.json (a path's stem), even one that does not load
        here (a DeepRacer route not pulled to this machine)."""
        try:
            return self._config_track(spec).name
        except TrackError:
            return Path(spec).stem if spec.endswith(".npy") else spec

    def track(self, name: str) -> dict[str, Any] | None:
        """Geometry of a track the run drives or was evaluated on, by its name; None for any other name (a URL
        must not make the server read an arbitrary file)."""
        for spec in self._config_tracks():
            if self._track_name(spec) == name:
                try:
                    return track_geometry(self._config_track(spec))
                except TrackError:
                    return None
        if name in known_track_names():  # an evaluation track given by name (racer train --eval-track)
            try:
                return track_geometry(self._config_track(name))
            except TrackError:  # a DeepRacer route not pulled to this machine
                return None
        return None


def track_geometry(track: Track) -> dict[str, Any]:
    """A track for the page to draw: centre line and borders in metres (mm precision), closed or not."""

    def points(a: Any) -> list[list[float]]:
        return [[round(float(x), 3), round(float(y), 3)] for x, y in a]

    return {
        "name": track.name,
        "closed": track.closed,
        "width": round(track.width, 3),
        "length": round(track.length, 3),
        "center": points(track.center),
        "inner": points(track.inner),
        "outer": points(track.outer),
    }
