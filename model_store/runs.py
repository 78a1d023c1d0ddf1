"""The run layout (checkpoints, pointers, run files) on top of any ObjectStore; ARCHITECTURE.md has the whole layout.

::

    runs/{run_id}/checkpoints/{version:09d}.pt     checkpoint bytes (produced by the caller)
    runs/{run_id}/checkpoints/{version:09d}.json   its metadata
    runs/{run_id}/checkpoints/{version:09d}.optimizer.pt
                                                   the optimizer's state, kept only where a resume (the newest) or
                                                   the collapse guard's roll-back (the best) needs it
    runs/{run_id}/checkpoints/{version:09d}.acting.pt
                                                   the acting copy (float16 weights) rollout workers load; runs
                                                   from before it existed have none, and workers read the .pt
    runs/{run_id}/latest.json, best.json           pointers: {"version": N, ...that checkpoint's metadata}
    runs/{run_id}/config.json                      the RunConfig (``write_config``/``read_config``)
    runs/{run_id}/metrics.jsonl                    one JSON row per training iteration (the trainer's;
                                                   ``read_metrics``)
    runs/{run_id}/evaluations/{version:09d}.json   one per evaluated checkpoint (the evaluator's;
                                                   ``read_evaluation``, ``read_evaluations``)
    runs/{run_id}/{name}                           run files: model_metadata.json, reward_function.py, ...

A checkpoint is whole once its .json exists: the .pt (and its optimizer state and acting copy) is written first, then
the .json, then (last) the pointer, so a crash at any point leaves every pointer naming a whole checkpoint. Readers
ignore a .pt without its .json.
"""

from __future__ import annotations

import json
import logging
import numbers
import re
import time
from pathlib import Path
from typing import Any, Literal

from pydantic import ValidationError

from common.config import RunConfig
from common.errors import OptionError, first_validation_error
from common.keys import RUN_ID, check_run_id
from model_store.store import ObjectStore, StoreError, StoreKeyError, check_key

log = logging.getLogger(__name__)

PointerName = Literal["latest", "best"]
POINTERS: tuple[str, ...] = ("latest", "best")

_CKPT_NAME = re.compile(r"^(\d{9})\.(pt|json)$")
_OPTIMIZER_NAME = re.compile(r"^(\d{9})\.optimizer\.pt$")
CONFIG_FILE = "config.json"
"""The run file of the run's RunConfig (common/config.py), read by every process of the run."""
METRICS_FILE = "metrics.jsonl"
"""The run file of training metrics, one JSON object per iteration."""
EVALUATIONS_DIR = "evaluations"
"""The run folder of evaluation records."""
_EVAL_NAME = re.compile(r"^(\d{9})\.json$")


TEACHER_FILE = "teacher/model.pt"
"""A distilling run's copy of its teacher's checkpoint (``RunConfig.distill``), written with the run's files: the run
keeps both policies, and its workers never read another run."""
TEACHER_META_FILE = "teacher/checkpoint.json"
"""That checkpoint's metadata as the teacher run stored it, with ``run_id`` and ``version`` naming its source."""


def evaluation_name(version: int) -> str:
    """Run file name of checkpoint ``version``'s evaluation: ``evaluations/{version:09d}.json``."""
    return f"{EVALUATIONS_DIR}/{_check_version(version):09d}.json"


def _check_version(version: int) -> int:
    # bool is an int subclass; True as a version is always a bug.
    if isinstance(version, bool) or not isinstance(version, int) or not 0 <= version < 10**9:
        raise OptionError(f"invalid checkpoint version {version!r}: an int in [0, 999999999]")
    return version


def _check_pointer(name: str) -> str:
    if name not in POINTERS:
        raise OptionError(f"invalid pointer {name!r}: 'latest' or 'best'")
    return name


def run_prefix(run_id: str) -> str:
    """``runs/{run_id}/``."""
    return f"runs/{check_run_id(run_id)}/"


SimTraceKind = Literal["training", "evaluation"]
_STAMP = re.compile(r"^\d{14}$")
_WORKER = re.compile(r"^\d+$")


def evaluation_stamp(epoch_s: float) -> str:
    """DRfC's name for an evaluation, its UTC start time as ``YYYYMMDDHHMMSS``."""
    import datetime as dt

    return dt.datetime.fromtimestamp(epoch_s, dt.UTC).strftime("%Y%m%d%H%M%S")


def simtrace_key(
    run_id: str, kind: SimTraceKind, iteration: int, worker: str | int = 0, *, evaluation: str | None = None
) -> str:
    """The store key of a sim-trace CSV in the run folder (the layout deepracer-utils reads: ``common/simtrace.py``).

    ``training``: ``runs/{run_id}/{worker}/training-simtrace/{iteration}-iteration.csv``, ``worker`` the worker
    index (one file for all the envs of a worker with several: ``rollout_worker.rollouts.Rollouts.take_simtrace``).
    ``evaluation``: ``runs/{run_id}/evaluation-{evaluation}/evaluation-simtrace/{iteration}-iteration.csv``,
    ``evaluation`` a 14-digit UTC stamp from :func:`evaluation_stamp` (DeepRacer evaluates with one worker, so
    ``worker`` is not part of it; deepracer-utils reads iteration 0 only).
    """
    if isinstance(iteration, bool) or not isinstance(iteration, numbers.Integral) or iteration < 0:
        raise ValueError(f"invalid iteration {iteration!r}: an int >= 0")
    if kind == "training":
        if evaluation is not None:
            raise ValueError("a training sim-trace has no evaluation stamp")
        if isinstance(worker, bool) or not _WORKER.match(str(worker)):
            raise ValueError(f"invalid worker {worker!r}: a worker index >= 0")
        return f"{run_prefix(run_id)}{int(worker)}/training-simtrace/{int(iteration)}-iteration.csv"
    if kind == "evaluation":
        if evaluation is None or not _STAMP.match(evaluation):
            raise ValueError(f"invalid evaluation stamp {evaluation!r}: YYYYMMDDHHMMSS (see evaluation_stamp)")
        return f"{run_prefix(run_id)}evaluation-{evaluation}/evaluation-simtrace/{int(iteration)}-iteration.csv"
    raise ValueError(f"invalid sim-trace kind {kind!r}: 'training' or 'evaluation'")


def local_runs_dir(store: str) -> Path:
    """The folder on this machine that holds the runs' local folders (``local_run_dir``): ``runs/`` in a directory
    store, ``./runs`` for a bucket."""
    root = Path(store) if "://" not in store else Path(".")
    return root / "runs"


def local_run_dir(store: str, run_id: str) -> Path:
    """The run's folder on this machine, for what is written as local files (role logs, TensorBoard, the record of
    a running ``racer train``'s Redis): the run's folder in a directory store, ``./runs/<run_id>`` for a bucket."""
    return local_runs_dir(store) / check_run_id(run_id)


def checkpoint_key(run_id: str, version: int) -> str:
    """Key of a checkpoint's bytes: ``runs/{run_id}/checkpoints/{version:09d}.pt``."""
    return f"{run_prefix(run_id)}checkpoints/{_check_version(version):09d}.pt"


def checkpoint_meta_key(run_id: str, version: int) -> str:
    """Key of a checkpoint's metadata: ``runs/{run_id}/checkpoints/{version:09d}.json``."""
    return f"{run_prefix(run_id)}checkpoints/{_check_version(version):09d}.json"


def optimizer_key(run_id: str, version: int) -> str:
    """Key of a checkpoint's optimizer state: ``runs/{run_id}/checkpoints/{version:09d}.optimizer.pt``."""
    return f"{run_prefix(run_id)}checkpoints/{_check_version(version):09d}.optimizer.pt"


def acting_key(run_id: str, version: int) -> str:
    """Key of a checkpoint's acting copy: ``runs/{run_id}/checkpoints/{version:09d}.acting.pt``."""
    return f"{run_prefix(run_id)}checkpoints/{_check_version(version):09d}.acting.pt"


def pointer_key(run_id: str, name: str) -> str:
    """Key of the ``latest`` or ``best`` pointer: ``runs/{run_id}/{name}.json``."""
    return f"{run_prefix(run_id)}{_check_pointer(name)}.json"


def _dumps(obj: dict[str, Any]) -> bytes:
    # allow_nan=False: NaN/Infinity are not JSON, and other readers (jq, JS, DeepRacer tools) reject them.
    return json.dumps(obj, indent=2, sort_keys=True, allow_nan=False).encode()


def _loads(store: ObjectStore, key: str, data: bytes) -> dict[str, Any]:
    """Parse a JSON object read from the store (json only: nothing from the store is unpickled)."""
    try:
        obj = json.loads(data)
    except (ValueError, UnicodeDecodeError):
        raise StoreError(f"malformed JSON in {store.key_uri(key)}") from None
    if not isinstance(obj, dict):
        raise StoreError(f"malformed JSON in {store.key_uri(key)}: not an object")
    return obj


class RunStore:
    """Checkpoints, pointers and run files of training runs, on any ObjectStore."""

    def __init__(self, store: ObjectStore) -> None:
        self.store = store

    # -- JSON helpers --------------------------------------------------------------------------------------------------

    def _read_json(self, key: str) -> dict[str, Any]:
        return _loads(self.store, key, self.store.get(key))

    def _read_json_or_none(self, key: str) -> dict[str, Any] | None:
        try:
            return self._read_json(key)
        except StoreKeyError:
            return None

    def _get_or_none(self, key: str) -> bytes | None:
        try:
            return self.store.get(key)
        except StoreKeyError:
            return None

    def _run_exists(self, run_id: str) -> bool:
        return next(iter(self.store.list(run_prefix(run_id))), None) is not None

    def _missing(self, run_id: str, what: str) -> StoreKeyError:
        """A StoreKeyError that says whether the run itself or only ``what`` in it is missing."""
        if not self._run_exists(run_id):
            return StoreKeyError(f"run {run_id!r} does not exist in {self.store.uri}")
        return StoreKeyError(f"run {run_id!r} has no {what} in {self.store.uri}")

    # -- checkpoints ---------------------------------------------------------------------------------------------------

    def save_checkpoint(
        self,
        run_id: str,
        version: int,
        payload: bytes,
        meta: dict[str, Any],
        *,
        optimizer: bytes | None = None,
        acting: bytes | None = None,
    ) -> dict[str, Any]:
        """Write the optimizer state and the acting copy (each if given), the .pt, then its .json, then LAST the
        ``latest`` pointer; return the full metadata.

        The metadata is ``meta`` plus ``run_id``, ``version``, ``size_bytes`` and ``created`` (epoch s, if absent).
        A whole checkpoint (its .json exists) is never overwritten: StoreError. A half-written one (a .pt left by a
        crash) is replaced. Calling again with the same ``meta`` (including ``created``) after a failure part-way
        finishes that save: a .json already stored with exactly these bytes only needs its pointer.
        """
        full = {**meta, "run_id": check_run_id(run_id), "version": _check_version(version), "size_bytes": len(payload)}
        full.setdefault("created", time.time())
        meta_bytes = _dumps(full)  # serialize first: unserializable meta must fail before anything is written
        meta_key = checkpoint_meta_key(run_id, version)
        stored = self._get_or_none(meta_key)
        if stored is not None and stored != meta_bytes:
            raise StoreError(f"checkpoint {version} of run {run_id!r} already exists: {self.store.key_uri(meta_key)}")
        if stored is None:
            if optimizer is not None:
                self.store.put(optimizer_key(run_id, version), bytes(optimizer))
            if acting is not None:
                self.store.put(acting_key(run_id, version), bytes(acting))
            self.store.put(checkpoint_key(run_id, version), bytes(payload))
            self.store.put(meta_key, meta_bytes)
        self.store.put(pointer_key(run_id, "latest"), _dumps({**full, "version": version}))
        return full

    def prune_checkpoints(self, run_id: str, keep_last: int) -> list[int]:
        """Delete whole checkpoints except the newest ``keep_last`` and those a pointer names; return the deleted.

        A checkpoint of DeepRacer's CNN with its Adam state is ~70 MB, so a long run keeps a window, as
        DeepRacer-for-Cloud does. The .json goes first, so a reader never finds metadata without weights.
        """
        doomed = self._prunable(run_id, sorted(self._versions(run_id)), keep_last)
        for v in doomed:
            self.store.delete(checkpoint_meta_key(run_id, v))
            self.store.delete(checkpoint_key(run_id, v))
            self.store.delete(optimizer_key(run_id, v))
            self.store.delete(acting_key(run_id, v))
        return doomed

    def prune_run(self, run_id: str, keep_last: int, dry_run: bool = False) -> dict[str, Any]:
        """Shrink a finished run: keep the newest ``keep_last`` checkpoints and those a pointer names, and the
        optimizer state of the newest only (what a resume reads). Returns what went (or, with ``dry_run``, would
        go): ``{"run_id", "checkpoints": [versions], "optimizer_states": [versions], "bytes": freed}``."""
        prefix = f"{run_prefix(run_id)}checkpoints/"
        sizes = {info.key: info.size for info in self.store.list(prefix)}
        versions = sorted(self._versions(run_id))
        if not versions:
            raise self._missing(run_id, "checkpoint")
        doomed = self._prunable(run_id, versions, keep_last)
        optimizers = [v for v in self._optimizer_versions(run_id) if v != versions[-1] and v not in doomed]
        freed = sum(
            sizes.get(key, 0)
            for v in doomed
            for key in (
                checkpoint_key(run_id, v),
                checkpoint_meta_key(run_id, v),
                optimizer_key(run_id, v),
                acting_key(run_id, v),
            )
        ) + sum(sizes.get(optimizer_key(run_id, v), 0) for v in optimizers)
        if not dry_run:
            self.prune_checkpoints(run_id, keep_last)
            self.keep_optimizer_states(run_id, {versions[-1]})
        return {"run_id": run_id, "checkpoints": doomed, "optimizer_states": optimizers, "bytes": freed}

    def _prunable(self, run_id: str, versions: list[int], keep_last: int) -> list[int]:
        """Of ``versions`` (ascending), those older than the newest ``keep_last`` that no pointer names."""
        pinned = {(self.pointer(run_id, name) or {}).get("version") for name in POINTERS}
        return [v for v in versions[: max(0, len(versions) - keep_last)] if v not in pinned]

    def _optimizer_versions(self, run_id: str) -> list[int]:
        """Versions whose optimizer state is stored, ascending."""
        prefix = f"{run_prefix(run_id)}checkpoints/"
        found = (_OPTIMIZER_NAME.match(info.key[len(prefix) :]) for info in self.store.list(prefix))
        return sorted(int(m.group(1)) for m in found if m)

    def evaluation_versions(self, run_id: str) -> list[int]:
        """Checkpoint versions that have an evaluation record, ascending."""
        prefix = f"{run_prefix(run_id)}{EVALUATIONS_DIR}/"
        names = (info.key[len(prefix) :] for info in self.store.list(prefix))
        return sorted(int(m.group(1)) for m in map(_EVAL_NAME.match, names) if m)

    def load_optimizer(self, run_id: str, version: int) -> bytes | None:
        """The optimizer state saved with checkpoint ``version``, or None where it was not kept."""
        return self._get_or_none(optimizer_key(run_id, version))

    def load_acting(self, run_id: str, version: int) -> bytes | None:
        """The acting copy saved with checkpoint ``version``, or None where there is none (a run from before acting
        copies, or a version pruned since): the caller then loads the checkpoint itself."""
        return self._get_or_none(acting_key(run_id, version))

    def keep_optimizer_states(self, run_id: str, keep: set[int]) -> list[int]:
        """Delete the optimizer state of every checkpoint not in ``keep``; return the versions it was deleted of.

        The optimizer (Adam's two moments) is twice the size of the weights, and only a resume (the newest
        checkpoint) or a roll-back (the best) reads it: a run keeps the weights of its last few checkpoints and
        the optimizer state of one or two."""
        doomed = [v for v in self._optimizer_versions(run_id) if v not in keep]
        for v in doomed:
            self.store.delete(optimizer_key(run_id, v))
        return doomed

    def _versions(self, run_id: str) -> set[int]:
        prefix = f"{run_prefix(run_id)}checkpoints/"
        return {
            int(m.group(1))
            for info in self.store.list(prefix)
            if (m := _CKPT_NAME.match(info.key[len(prefix) :])) and m.group(2) == "json"
        }

    def newest_whole(self, run_id: str) -> int | None:
        """The highest version whose .pt and .json are both stored, or None.

        It is the ``latest`` pointer's version, or newer when a writer died between a checkpoint's .json and the
        pointer: resuming from it loses nothing that was whole."""
        prefix = f"{run_prefix(run_id)}checkpoints/"
        names = {info.key[len(prefix) :] for info in self.store.list(prefix)}
        whole = [v for v in self._versions(run_id) if f"{v:09d}.pt" in names]
        return max(whole, default=None)

    def checkpoint_meta(self, run_id: str, version: int) -> dict[str, Any]:
        """The metadata of a whole checkpoint; StoreKeyError if the run, the .json or the .pt is missing."""
        meta = self._read_json_or_none(checkpoint_meta_key(run_id, version))
        if meta is None or not self.store.exists(checkpoint_key(run_id, version)):
            raise self._missing(run_id, f"checkpoint {version}")
        return meta

    def set_pointer(self, run_id: str, name: PointerName, version: int) -> dict[str, Any]:
        """Point ``latest`` or ``best`` at a whole checkpoint; return the pointer written."""
        _check_pointer(name)
        pointer = {**self.checkpoint_meta(run_id, version), "version": version}
        self.store.put(pointer_key(run_id, name), _dumps(pointer))
        return pointer

    def pointer(self, run_id: str, name: PointerName) -> dict[str, Any] | None:
        """The ``latest`` or ``best`` pointer of a run, or None if it has none."""
        key = pointer_key(run_id, name)
        pointer = self._read_json_or_none(key)
        version = None if pointer is None else pointer.get("version")
        if pointer is not None and (isinstance(version, bool) or not isinstance(version, int)):
            raise StoreError(f"malformed pointer {self.store.key_uri(key)}: no integer 'version'")
        return pointer

    def resolve(self, run_id: str, version: int | str) -> int:
        """A version number from an int, ``"latest"``, ``"best"`` or a decimal string (``--checkpoint 12``)."""
        if isinstance(version, str) and version.isdecimal():
            return _check_version(int(version))
        if isinstance(version, str):
            pointer = self.pointer(run_id, _check_pointer(version))  # type: ignore[arg-type]
            if pointer is None:
                raise self._missing(run_id, f"{version} checkpoint")
            return pointer["version"]
        return _check_version(version)

    def load_checkpoint(self, run_id: str, version: int | str) -> tuple[bytes, dict[str, Any]]:
        """The bytes and metadata of a checkpoint given as a version, ``"latest"`` or ``"best"``.

        StoreKeyError if the run, the pointer or the checkpoint does not exist; StoreError if the bytes read do not
        match the recorded size.
        """
        number = self.resolve(run_id, version)
        meta = self.checkpoint_meta(run_id, number)
        try:
            payload = self.store.get(checkpoint_key(run_id, number))
        except StoreKeyError:  # deleted since checkpoint_meta looked
            raise self._missing(run_id, f"checkpoint {number}") from None
        expected = meta.get("size_bytes")
        if isinstance(expected, int) and expected != len(payload):
            key_uri = self.store.key_uri(checkpoint_key(run_id, number))
            raise StoreError(f"checkpoint {key_uri} is {len(payload)} bytes, its metadata says {expected}")
        return payload, meta

    def list_runs(self) -> list[str]:
        """The run ids in the store, sorted."""
        runs = {info.key.split("/")[1] for info in self.store.list("runs/") if info.key.count("/") >= 2}
        return sorted(r for r in runs if RUN_ID.match(r))

    def list_checkpoints(self, run_id: str) -> list[dict[str, Any]]:
        """Metadata of each whole checkpoint in version order, with ``size_bytes`` and ``latest``/``best`` flags.

        A .pt without its .json (half-written) and a .json without its .pt are skipped.
        """
        prefix = f"{run_prefix(run_id)}checkpoints/"
        sizes: dict[int, int] = {}
        metas: set[int] = set()
        for info in self.store.list(prefix):
            m = _CKPT_NAME.match(info.key[len(prefix) :])
            if m and m.group(2) == "pt":
                sizes[int(m.group(1))] = info.size
            elif m:
                metas.add(int(m.group(1)))
        flags = {name: (self.pointer(run_id, name) or {}).get("version") for name in POINTERS}
        out = []
        for version in sorted(metas & sizes.keys()):
            meta = self._read_json_or_none(checkpoint_meta_key(run_id, version))
            if meta is None:  # pruned since the listing: a live trainer prunes as it checkpoints
                continue
            # The listed size is the truth on disk; the flags are computed, never stored.
            meta.update(run_id=run_id, version=version, size_bytes=sizes[version])
            meta.update({name: flags[name] == version for name in POINTERS})
            out.append(meta)
        return out

    # -- run files -----------------------------------------------------------------------------------------------------

    def _file_key(self, run_id: str, name: str) -> str:
        if name in ("latest.json", "best.json") or name == "checkpoints" or name.startswith("checkpoints/"):
            raise ValueError(f"run file name {name!r} is reserved for checkpoints and pointers")
        key = f"{run_prefix(run_id)}{name}"
        try:
            return check_key(key)
        except StoreError:
            raise ValueError(f"invalid run file name {name!r}") from None

    def write_file(self, run_id: str, name: str, data: bytes | str) -> None:
        """Write a run file such as ``model_metadata.json`` or ``reward_function.py`` (str is written as UTF-8)."""
        self.store.put(self._file_key(run_id, name), data.encode() if isinstance(data, str) else bytes(data))

    def read_file(self, run_id: str, name: str) -> bytes:
        """Read a run file; StoreKeyError naming the run and file if it is missing."""
        try:
            return self.store.get(self._file_key(run_id, name))
        except StoreKeyError:
            raise self._missing(run_id, f"file {name!r}") from None

    def write_config(self, run: RunConfig) -> None:
        """Store ``run`` as its run's config.json (indented JSON)."""
        self.write_file(run.run_id, CONFIG_FILE, run.model_dump_json(indent=2))

    def read_config(self, run_id: str) -> RunConfig:
        """The run's RunConfig from its config.json.

        StoreKeyError naming the run if it (or its config.json) is missing; StoreError in one line naming the run,
        the file and the first bad key and value if the file does not validate (``run r1: config.json: env.track:
        Input should be a valid string (got 5)``).
        """
        data = self.read_file(run_id, CONFIG_FILE)
        try:
            return RunConfig.model_validate_json(data)
        except ValidationError as exc:
            raise StoreError(f"run {run_id}: {CONFIG_FILE}: {first_validation_error(exc)}") from None

    # -- what the trainer and the evaluator recorded -------------------------------------------------------------------

    def read_metrics(self, run_id: str, missing_ok: bool = False) -> list[dict[str, Any]]:
        """The rows of the run's metrics.jsonl (one per training iteration) in file order.

        A line that is not a JSON object is skipped with a warning. Without the file: StoreKeyError naming the run
        and file, or with ``missing_ok`` an empty list (a run that has not finished an update yet).
        """
        try:
            text = self.read_file(run_id, METRICS_FILE).decode("utf-8", errors="replace")
        except StoreKeyError:
            if missing_ok:
                return []
            raise
        rows = []
        for number, line in enumerate(text.splitlines(), 1):
            row = _json_object(line) if line.strip() else None
            if row is None and line.strip():
                log.warning("run %r: skipping malformed line %d of %s", run_id, number, METRICS_FILE)
            elif row is not None:
                rows.append(row)
        return rows

    def read_evaluation(self, run_id: str, version: int) -> dict[str, Any]:
        """The evaluation record of checkpoint ``version``; StoreKeyError if it is missing, StoreError if it is not
        a JSON object."""
        name = evaluation_name(version)
        evaluation = _json_object(self.read_file(run_id, name))
        if evaluation is None:
            raise StoreError(f"malformed evaluation {self.store.key_uri(run_prefix(run_id) + name)}")
        return evaluation

    def read_evaluations(self, run_id: str) -> list[dict[str, Any]]:
        """Every readable evaluation record of a run in version order, each with its ``version`` (taken from the file
        name); a malformed one, or one deleted since the listing, is skipped with a warning."""
        out = []
        for version in self.evaluation_versions(run_id):
            try:
                evaluation = self.read_evaluation(run_id, version)
            except StoreError as exc:  # includes a file deleted since the listing
                log.warning("run %r: skipping evaluation %d: %s", run_id, version, exc)
                continue
            out.append({**evaluation, "version": version})  # the file name is the truth for the version
        return out


def _json_object(text: str | bytes) -> dict[str, Any] | None:
    """The JSON object in ``text``, or None if it is not one (json only: nothing from the store is unpickled)."""
    try:
        obj = json.loads(text)
    except (ValueError, UnicodeDecodeError):
        return None
    return obj if isinstance(obj, dict) else None


def list_models(store: ObjectStore, run_id: str | None = None) -> list[dict[str, Any]]:
    """One dict per whole checkpoint across all runs (or one run), for ``racer models ls``.

    Each has the checkpoint's metadata plus, always, ``run_id``, ``version``, ``env_steps`` (None if not recorded),
    ``created``, ``size_bytes``, ``latest`` and ``best``. An unknown ``run_id`` gives an empty list.
    """
    runs = RunStore(store)
    out = []
    for rid in [check_run_id(run_id)] if run_id is not None else runs.list_runs():
        for meta in runs.list_checkpoints(rid):
            meta.setdefault("env_steps", None)
            meta.setdefault("created", None)
            out.append({**meta, "run_id": rid})
    return out
