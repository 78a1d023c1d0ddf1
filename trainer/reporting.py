"""What the trainer reports: a row per update in metrics.jsonl, TensorBoard scalars (its own and the evaluator's),
and which workers are alive (their heartbeats), for the status ``racer train`` shows."""

from __future__ import annotations

import json
import logging
import statistics
import time

from common.bus import Bus
from common.protocol import EpisodeSummary, Segment
from common.retry import Outage
from common.tensorboard import tensorboard_without_tensorflow
from model_store import RunStore
from model_store.runs import METRICS_FILE, local_run_dir
from trainer.guard import EVALUATION_WINDOW, Stability
from trainer.intake import Stats

log = logging.getLogger("racer.trainer")


def summary_writer(store: str, run_id: str):  # noqa: ANN201 - torch's SummaryWriter, imported late
    """A TensorBoard writer in the run's folder (TensorBoard writes local files: ./runs/<id>/ for an S3 store)."""
    tensorboard_without_tensorflow()
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter(log_dir=str(local_run_dir(store, run_id) / "tensorboard"))


def metrics_row(
    stats: Stats,
    version: int,
    stability: Stability,
    segments: list[Segment],
    batch_steps: int,
    *,
    lr: float,
    train_s: float,
    losses: dict,
) -> dict:
    """One update's row of metrics.jsonl: the run's counters, the figures of the ``segments`` it trained on (their
    episodes, their policy lag against the version they trained: ``version - 1``), its learning rate and losses."""
    episodes = [e for seg in segments for e in seg.episodes]
    lags = [version - 1 - seg.policy_version for seg in segments]
    laps = [e.lap_time_s for e in episodes if e.lap_time_s]
    return {
        "iteration": stats.iteration,
        "policy_version": version,
        "env_steps": stats.env_steps,
        "episodes": len(episodes),
        "batch_steps": batch_steps,
        "mean_progress": statistics.fmean(e.progress for e in episodes) if episodes else 0.0,
        "mean_reward": statistics.fmean(e.reward for e in episodes) if episodes else 0.0,
        "laps_completed": sum(e.status == "lap_complete" for e in episodes),
        "mean_episode_steps": statistics.fmean(e.steps for e in episodes) if episodes else 0.0,
        "mean_lap_time_s": statistics.fmean(laps) if laps else None,
        "learning_rate": lr,
        "steps_per_s": stats.steps_per_s(),
        "mean_policy_lag": statistics.fmean(lags) if lags else 0.0,
        "train_s": train_s,
        "dropped": dict(stats.dropped),
        "dropped_steps": stats.dropped_steps,
        "collapses": stability.collapses,
        "rollbacks": stability.rollbacks,
        "slow_rollbacks": stability.slow_rollbacks,
        "time": time.time(),
        **{k: float(v) for k, v in losses.items()},
    }


class Reporter:
    """The run's metrics.jsonl (rewritten whole: object stores can't append) and its TensorBoard writer."""

    def __init__(self, runs: RunStore, run_id: str, store_outage: Outage, tb: object | None) -> None:
        self.runs, self.run_id, self.store_outage, self.tb = runs, run_id, store_outage, tb
        self.metrics: list[dict] = []
        self.tb_evaluated = -1
        """Newest evaluated version whose figures are in TensorBoard (``tensorboard_evaluations``)."""

    def trained_env_steps(self) -> int:
        """The env steps the last update trained on: those received (``Stats.env_steps``) less those still waiting
        in the buffer for the next update, as metrics.jsonl counts them."""
        return int(self.metrics[-1]["env_steps"]) if self.metrics else 0

    def record(self, row: dict, losses: dict, segments: list[Segment]) -> None:
        """Append one update's row (``metrics_row``) to metrics.jsonl, and its figures and the episodes of its
        ``segments`` to TensorBoard."""
        episodes = [e for seg in segments for e in seg.episodes]
        self.metrics.append(row)
        text = "".join(json.dumps(m) + "\n" for m in self.metrics)
        self.store_outage.call("write metrics", lambda: self.runs.write_file(self.run_id, METRICS_FILE, text))
        self._tensorboard(row, losses, episodes)

    def _tensorboard(self, row: dict, losses: dict, episodes: list[EpisodeSummary]) -> None:
        """The same figures as TensorBoard scalars (trainer/…, and episode/… per worker episode)."""
        if self.tb is None:
            return
        step = row["env_steps"]
        for name, value in losses.items():
            self.tb.add_scalar(f"trainer/{name}", value, step)
        for name, key in (("learning_rate", "learning_rate"), ("policy_lag", "mean_policy_lag")):
            self.tb.add_scalar(f"trainer/{name}", row[key], step)
        for name in ("steps_per_s", "mean_progress", "collapses", "rollbacks"):
            self.tb.add_scalar(f"trainer/{name}", row[name], step)
        for e in episodes:
            self.tb.add_scalar("episode/reward", e.reward, step)
            self.tb.add_scalar("episode/progress", e.progress, step)
            self.tb.add_scalar("episode/length", e.steps, step)
            if e.lap_time_s is not None:
                self.tb.add_scalar("episode/lap_time_s", e.lap_time_s, step)
        self.tb.flush()

    def rollback(self, rollbacks: int, env_steps: int) -> None:
        """A rollback, as it happens (the next update's row counts it too)."""
        if self.tb is not None:
            self.tb.add_scalar("trainer/rollbacks", rollbacks, env_steps)

    def tensorboard_evaluations(self, bus: Bus, env_steps: int) -> int:
        """The evaluator's new summaries as TensorBoard scalars (``evaluation/…``, at the evaluated checkpoint's env
        steps, beside the training curves; ``env_steps`` where a summary has none); returns how many were new.

        The trainer writes them, not the evaluator: it owns the run's one TensorBoard writer, and the evaluator may
        run on another machine (compose), whose summaries reach the trainer through Redis as the collapse guard's do.
        """
        if self.tb is None:
            return 0
        summaries, _ = bus.evaluations(last=EVALUATION_WINDOW)
        new = sorted((s for s in summaries if s.version > self.tb_evaluated), key=lambda s: s.version)
        for s in new:
            step = env_steps if s.env_steps is None else s.env_steps
            self.tb.add_scalar("evaluation/completion_rate", s.completion_rate, step)
            self.tb.add_scalar("evaluation/mean_progress", s.mean_progress, step)
            self.tb.add_scalar("evaluation/score", s.score, step)
            for name, value in (("mean_lap_s", s.mean_lap_s), ("best_lap_s", s.best_lap_s)):
                if value is not None:  # no lap completed: no lap time
                    self.tb.add_scalar(f"evaluation/{name}", value, step)
            self.tb_evaluated = s.version
        if new:
            self.tb.flush()
        return len(new)

    def close(self) -> None:
        """Close the TensorBoard writer (its last events reach the file)."""
        if self.tb is not None:
            self.tb.close()


class WorkerWatch:
    """Which workers are alive, from their heartbeat keys; logs one that goes silent, and one that comes back."""

    def __init__(self, bus: Bus, heartbeat_ttl_s: float) -> None:
        self.bus, self.heartbeat_ttl_s = bus, heartbeat_ttl_s
        self.live: dict[str, dict] = {}
        """Last heartbeat of each worker seen alive (worker id → Heartbeat fields)."""
        self.silent: dict[str, dict] = {}
        """Workers whose heartbeat expired: worker id → their last heartbeat."""

    def workers(self) -> tuple[list[dict], int]:
        """Live workers (SCAN, never KEYS) and how many heartbeat keys could not be read."""
        beats, bad = self.bus.heartbeats()
        out = [hb.model_dump() for hb in beats]
        self._note_silent({w["worker_id"]: w for w in out})
        return out, bad

    def _note_silent(self, alive: dict[str, dict]) -> None:
        for wid, hb in self.live.items():
            if wid not in alive and wid not in self.silent:
                self.silent[wid] = hb
                log.warning(
                    "worker %s is silent: no heartbeat for %.0f s (TTL %.0f s expired); last seen at policy v%d "
                    "after %d segments; training goes on without it",
                    wid,
                    time.time() - hb["time"],
                    self.heartbeat_ttl_s,
                    hb["policy_version"],
                    hb["segments"],
                )
        for wid in alive:
            if self.silent.pop(wid, None) is not None:
                log.warning("worker %s is sending heartbeats again", wid)
        self.live.update(alive)
