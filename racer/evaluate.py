"""``racer eval``: evaluate any checkpoint of any run from a store, on any track."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from common.config import RunConfig
from model_store import RunStore, open_store
from model_store.localize import localize_env
from trainer.evaluator import EvalSettings, evaluate_checkpoint


def run_eval(
    run_id: str,
    store: str,
    s3_endpoint: str | None,
    checkpoint: str,
    tracks: list[str],
    episodes: int,
    both_directions: bool,
    action_noise: float,
    sim_trace: Path | None = None,
    video: Path | None = None,
) -> dict:
    """Evaluate and return the record (summary and trials); optionally write a sim-trace CSV and a video."""
    runs = RunStore(open_store(store, s3_endpoint))
    run = RunConfig.model_validate_json(runs.read_file(run_id, "config.json"))
    version: int | str = int(checkpoint) if checkpoint.isdigit() else checkpoint
    settings = EvalSettings(
        episodes=episodes, both_directions=both_directions, action_noise=action_noise, tracks=tracks
    )
    with tempfile.TemporaryDirectory(prefix="racer-eval-") as tmp:
        env_cfg = localize_env(run, runs, Path(tmp))
        return evaluate_checkpoint(runs, run, env_cfg, version, settings)


def models_table(store: str, s3_endpoint: str | None, run_id: str | None) -> list[dict]:
    """``racer models ls``: each checkpoint's metadata (without the bulky run config) and its evaluation figures."""
    from model_store import StoreKeyError, list_models
    from trainer.evaluator import evaluation_key

    obj_store = open_store(store, s3_endpoint)
    runs = RunStore(obj_store)
    rows = []
    for meta in list_models(obj_store, run_id):
        row = {k: v for k, v in meta.items() if k != "config"}
        try:
            ev = json.loads(runs.read_file(row["run_id"], evaluation_key(int(row["version"]))))
            row["evaluation"] = {k: ev.get(k) for k in ("completion_rate", "mean_progress", "best_lap_s", "score")}
        except (StoreKeyError, ValueError):
            row["evaluation"] = None
        rows.append(row)
    return rows
