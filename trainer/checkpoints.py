"""Checkpoint and publish: the run's files, its checkpoints (pointer last), their pruning, and the policy version
announced in Redis for the workers and the evaluator."""

from __future__ import annotations

import contextlib
import json
import logging
import time

from common.bus import Bus
from common.config import RunConfig
from common.protocol import PolicyVersion
from common.retry import Outage
from common.weights import acting_to_bytes, checkpoint_to_bytes, state_dict_to_bytes
from model_store import RunStore, StoreKeyError
from model_store.runs import METRICS_FILE, TEACHER_FILE, TEACHER_META_FILE, checkpoint_key

log = logging.getLogger("racer.trainer")

MIRRORS = {"model_metadata.json": "model/", "hyperparameters.json": "ip/"}
"""deepracer-utils looks for DeepRacer's copies of these two run files in these folders."""


class Checkpoints:
    """One run's checkpoints in the store and its policy key in Redis; store calls ride out outages."""

    def __init__(self, run: RunConfig, runs: RunStore, bus: Bus, store_outage: Outage) -> None:
        self.run, self.runs, self.bus, self.store_outage = run, runs, bus, store_outage
        self.run_id = run.run_id

    def write_run_files(self, files: dict[str, bytes]) -> None:
        """A new run's files (and their DeepRacer copies), a distilling run's copy of its teacher, and its
        ``config.json`` last (a run is whole once it has one)."""
        for name, data in files.items():
            self.runs.write_file(self.run_id, name, data)
            mirror = MIRRORS.get(name)
            if mirror:
                self.runs.write_file(self.run_id, mirror + name, data)
        if self.run.distill is not None:
            self.copy_teacher()
        self.runs.write_config(self.run)

    def copy_teacher(self) -> None:
        """Copy the checkpoint ``run.distill.teacher`` names (``RUN:VERSION``) into this run (``TEACHER_FILE``, its
        metadata beside it): the run keeps both policies, and its workers read the copy."""
        source, _, version = self.run.distill.teacher.partition(":")
        payload, meta = self.runs.load_checkpoint(source, int(version))
        self.runs.write_file(self.run_id, TEACHER_FILE, payload)
        meta = {**meta, "run_id": source, "version": int(version)}
        self.runs.write_file(self.run_id, TEACHER_META_FILE, json.dumps(meta, indent=2, allow_nan=False))

    def save(self, version: int, model: dict, optimizer: dict, meta: dict) -> dict:
        """Save ``version`` (``model`` and ``optimizer`` state dicts, ``meta`` into its metadata with the run's
        config); through a store outage, retry the same bytes and metadata (its ``created`` time too) until it is
        whole."""
        payload = checkpoint_to_bytes(model)
        acting = acting_to_bytes(model)  # what workers load (float16 weights, half the bytes)
        optimizer_bytes = state_dict_to_bytes(optimizer)
        meta = {
            **{k: meta[k] for k in ("env_steps", "episodes", "iteration")},
            "config": json.loads(self.run.model_dump_json()),
            **{k: v for k, v in meta.items() if k not in ("env_steps", "episodes", "iteration")},
        }
        return self.store_outage.call(
            f"save checkpoint {version}",
            lambda: self.runs.save_checkpoint(
                self.run_id, version, payload, meta, optimizer=optimizer_bytes, acting=acting
            ),
        )

    def prune(self, keep_optimizers: set[int]) -> None:
        """Keep the newest ``keep_checkpoints`` checkpoints (and the pointed ones) and the optimizer states of
        ``keep_optimizers`` only."""
        self.runs.prune_checkpoints(self.run_id, self.run.keep_checkpoints)  # with their optimizer states
        self.runs.keep_optimizer_states(self.run_id, keep_optimizers)

    def best_version(self) -> int | None:
        """The version the ``best`` pointer names, if any."""
        best = (self.runs.pointer(self.run_id, "best") or {}).get("version")
        return best if isinstance(best, int) else None

    def publish(self, version: int) -> None:
        """Announce ``version`` in Redis: workers and the evaluator load it from the store."""
        key = checkpoint_key(self.run_id, version)
        self.bus.publish_policy(PolicyVersion(version=version, checkpoint_key=key, created=time.time()))

    def newest(self) -> tuple[bytes, bytes | None, dict]:
        """The newest whole checkpoint (weights, optimizer state, metadata) to resume from; the ``latest`` pointer
        is repaired if it lags."""
        newest = self.runs.newest_whole(self.run_id)
        pointer = (self.runs.pointer(self.run_id, "latest") or {}).get("version")
        if newest is None:
            raise StoreKeyError(f"run {self.run_id!r} has no whole checkpoint to resume from in {self.runs.store.uri}")
        if pointer != newest:
            # The previous trainer died after writing checkpoint `newest` whole but before moving the pointer.
            log.warning("latest pointer names version %s but version %d is whole: resuming from it", pointer, newest)
            self.runs.set_pointer(self.run_id, "latest", newest)
        payload, meta = self.runs.load_checkpoint(self.run_id, newest)
        return payload, self.runs.load_optimizer(self.run_id, newest), meta

    def metrics(self) -> list[dict]:
        """The rows of the run's metrics.jsonl (none before the first update)."""
        with contextlib.suppress(StoreKeyError):
            lines = self.runs.read_file(self.run_id, METRICS_FILE).decode().splitlines()
            return [json.loads(line) for line in lines if line.strip()]
        return []

    def pretrained(self) -> tuple[bytes, str, object]:
        """The weights ``run.pretrained`` names: their bytes, the source run and the source version."""
        source, _, which = str(self.run.pretrained).partition(":")
        payload, meta = self.runs.load_checkpoint(source, which)
        return payload, source, meta.get("version")
