"""The collapse guard: it watches the evaluator's robust evaluations and says when the run must roll back.

``CollapseWatch`` decides from the summaries (a streak of ``collapse_patience`` collapsed evaluations newer than the
``best`` checkpoint); ``CollapseGuard`` reads them (Redis) and the best's evaluation (the store), keeps the run's
``Stability`` (kept in every checkpoint's metadata) and words each rollback. The trainer (``trainer/process.py``)
does the rollback itself: the weights, the version, the checkpoint.
"""

from __future__ import annotations

import json
import logging
import statistics
from dataclasses import dataclass, field
from typing import NamedTuple

from common.bus import Bus
from common.hyperparams import Hyperparameters
from common.retry import Outage
from model_store import RunStore, StoreKeyError
from model_store.runs import evaluation_name

log = logging.getLogger("racer.trainer")

EVALUATION_WINDOW = 64
"""Newest evaluation summaries read from Redis each time: the evaluator adds one per checkpoint it scores (tens of
seconds each), so far fewer than this arrive between two looks a second apart."""


@dataclass
class Stability:
    """What the collapse guard has done to the run; kept in every checkpoint's metadata, so a resumed run keeps it."""

    lr_scale: float = 1.0
    """Product of ``collapse_lr_factor`` over the rollbacks so far, never below ``collapse_lr_floor``
    (:func:`rolled_back_lr_scale`): it multiplies the scheduled learning rate."""
    collapses: int = 0
    """Collapses detected."""
    rollbacks: int = 0
    """Collapses rolled back (one fewer than ``collapses`` only if the best checkpoint could not be read)."""
    floor: int = 0
    """First version of the current lineage (the version a rollback published): evaluations and segments of older
    versions belong to the abandoned policies and are ignored."""
    slow_rollbacks: int = 0
    """Rollbacks whose streak held an evaluation collapsed by its pace alone (``collapse_slowdown``), not by its
    completion: so a run's figures say which rule acted."""

    @classmethod
    def from_meta(cls, meta: dict) -> Stability:
        """The state saved in a checkpoint's metadata; the initial state for a checkpoint from before the guard."""
        saved = meta.get("stability") or {}
        return cls(
            lr_scale=float(saved.get("lr_scale", 1.0)),
            collapses=int(saved.get("collapses", 0)),
            rollbacks=int(saved.get("rollbacks", 0)),
            floor=int(saved.get("floor", 0)),
            slow_rollbacks=int(saved.get("slow_rollbacks", 0)),
        )


def rolled_back_lr_scale(scale: float, factor: float, floor: float) -> float:
    """The learning-rate scale after one more rollback: ``scale * factor``, but not below ``floor`` (nor above
    ``scale``: a floor added to a resumed run whose scale is already lower does not raise it)."""
    return min(scale, max(scale * factor, floor))


def is_collapsed(completion: float, best_completion: float, min_best: float, drop: float) -> bool:
    """True when an evaluation's completion has collapsed against the best checkpoint's.

    Only a best that completes at least ``min_best`` of its trials can collapse (``racer train`` evaluates 6 or 12
    trials: one lap more or less is noise); collapsed means at most ``best_completion * (1 - drop)``: a relative
    drop, so 0.5 means "half the best's completion or less" whatever the best's.
    """
    return best_completion >= min_best and completion <= best_completion * (1.0 - drop)


def is_slower(mean_lap_s: float | None, best_mean_lap_s: float | None, slowdown: float | None) -> bool:
    """True when an evaluation's mean lap is more than ``1 + slowdown`` times the best checkpoint's (never when
    ``slowdown`` is None or either evaluation finished no lap)."""
    if slowdown is None or mean_lap_s is None or best_mean_lap_s is None:
        return False
    return mean_lap_s > best_mean_lap_s * (1.0 + slowdown)


def _mean_lap(record: dict) -> float | None:
    """An evaluation record's mean lap, s: its ``mean_lap_s``, or from its ``lap_times_s`` (records from before
    the evaluator wrote ``mean_lap_s``); None when it has no lap."""
    if record.get("mean_lap_s") is not None:
        return float(record["mean_lap_s"])
    laps = [float(lap) for lap in record.get("lap_times_s") or []]
    return statistics.fmean(laps) if laps else None


class BestEvaluation(NamedTuple):
    """What the collapse guard compares new evaluations with: the ``best`` checkpoint's."""

    version: int
    completion: float
    mean_lap_s: float | None = None


@dataclass
class CollapseWatch:
    """The collapse guard's memory: the evaluations it has looked at, and the current streak of collapsed ones.

    A streak counts consecutive evaluated checkpoints newer than the best that have all collapsed; any other
    evaluation (a good one, the best itself, an older one) ends it. ``patience`` of them in a row is a collapse:
    with 2 (the default), one unlucky evaluation is not enough, and a real collapse (issue 16 saw 5 or 6 versions
    in a row at 0 %) costs one checkpoint more.
    """

    min_best: float
    drop: float
    patience: int
    slowdown: float | None = None
    """``collapse_slowdown``: an evaluation this much slower than the best (mean lap) counts too; None: never."""
    floor: int = 0
    seen: int = -1
    """Newest version looked at."""
    streak: list[dict] = field(default_factory=list)

    def fresh(self, evaluations: list[dict]) -> list[dict]:
        """The summaries not looked at yet, of the current lineage, oldest first."""
        return sorted(
            (e for e in evaluations if e["version"] > self.seen and e["version"] >= self.floor),
            key=lambda e: e["version"],
        )

    def observe(self, evaluation: dict, best: tuple[int, float] | tuple[int, float, float | None] | None) -> bool:
        """Look at one new summary (``version``, ``completion_rate``, optionally ``mean_lap_s``) given the best
        (version, completion[, mean lap]), in version order; True when it completes a streak of ``patience``
        collapsed evaluations."""
        version = evaluation["version"]
        if version <= self.seen or version < self.floor:
            return False
        self.seen = version
        if not (best is not None and version > best[0] and self.collapsed(evaluation, BestEvaluation(*best))):
            self.streak = []
            return False
        self.streak.append(evaluation)
        return len(self.streak) >= self.patience

    def collapsed(self, evaluation: dict, best: BestEvaluation) -> bool:
        """One evaluation against the best: lost completion (``is_collapsed``) or, once the best completes
        ``min_best`` of its trials, a mean lap ``slowdown`` slower (``is_slower``)."""
        if is_collapsed(evaluation["completion_rate"], best.completion, self.min_best, self.drop):
            return True
        slower = is_slower(evaluation.get("mean_lap_s"), best.mean_lap_s, self.slowdown)
        return best.completion >= self.min_best and slower

    def restart(self, floor: int) -> None:
        """Forget the streak; from now on look only at versions from ``floor`` on."""
        self.floor, self.streak = floor, []


class CollapseGuard:
    """The collapse guard of one run: what it has seen (``watch``) and done (``stability``), and its reads."""

    def __init__(
        self, hp: Hyperparameters, run_id: str, bus: Bus, runs: RunStore, *, redis_outage: Outage, store_outage: Outage
    ) -> None:
        self.hp, self.run_id, self.bus, self.runs = hp, run_id, bus, runs
        self.redis_outage, self.store_outage = redis_outage, store_outage
        self.stability = Stability()
        self.watch = CollapseWatch(hp.collapse_min_best, hp.collapse_drop, hp.collapse_patience, hp.collapse_slowdown)

    def resume(self, meta: dict) -> None:
        """Take up the state a checkpoint's metadata saved."""
        self.stability = Stability.from_meta(meta)
        self.watch.restart(self.stability.floor)

    def collapse(self) -> tuple[BestEvaluation, list[dict]] | None:
        """Read the evaluator's new summaries; the best and the streak of collapsed evaluations when they complete
        a collapse (``CollapseWatch``), else None.

        The evaluator stores each evaluation (and moves ``best``) before it pushes the summary to Redis, so the
        best read here already accounts for every summary read.
        """
        fresh = self.redis_outage.call("read the evaluations", self._new_evaluations)
        if not fresh:
            return None
        best = self.store_outage.call("read the best evaluation", self._best_evaluation)
        for evaluation in fresh:
            if self.watch.observe(evaluation, best) and best is not None:
                return best, list(self.watch.streak)
        return None

    def _new_evaluations(self) -> list[dict]:
        """The evaluator's summaries (``trainer.evaluator._report``) the watch has not looked at yet."""
        # A malformed entry (not the evaluator's) is skipped: it says nothing about a checkpoint.
        summaries, _ = self.bus.evaluations(last=EVALUATION_WINDOW)
        return self.watch.fresh([s.model_dump() for s in summaries])

    def _best_evaluation(self) -> BestEvaluation | None:
        """The ``best`` checkpoint's evaluation (version, completion rate, mean lap), or None while there is none."""
        pointer = self.runs.pointer(self.run_id, "best")
        if pointer is None:
            return None
        version = int(pointer["version"])
        try:
            record = json.loads(self.runs.read_file(self.run_id, evaluation_name(version)))
            return BestEvaluation(version, float(record["completion_rate"]), _mean_lap(record))
        except (StoreKeyError, KeyError, TypeError, ValueError):
            return None

    def read_best(self, version: int) -> tuple[bytes, bytes | None] | None:
        """A collapse: the best checkpoint's weights and optimizer state (None where not kept), or None (counted as
        a collapse only, and logged) when the checkpoint cannot be read."""
        self.stability.collapses += 1
        try:
            payload, _ = self.store_outage.call(
                f"read best checkpoint {version}", lambda: self.runs.load_checkpoint(self.run_id, version)
            )
            optimizer = self.store_outage.call(
                f"read best checkpoint {version}'s optimizer", lambda: self.runs.load_optimizer(self.run_id, version)
            )
        except StoreKeyError as exc:
            log.warning("collapse guard: collapse %d detected but not rolled back: %s", self.stability.collapses, exc)
            self.watch.restart(self.watch.floor)
            return None
        if optimizer is None:  # not kept (a best from before the guard was on): its weights, a fresh optimizer
            log.warning("collapse guard: v%d's optimizer state was not kept; rolling back its weights", version)
        return payload, optimizer

    def rolled_back(self, best: BestEvaluation, collapsed: list[dict], version: int) -> None:
        """The run went back to ``best`` as ``version``: a lower learning-rate scale, and from now on only versions
        from ``version`` on count (older segments and evaluations belong to the abandoned policies)."""
        hp, stability = self.hp, self.stability
        stability.lr_scale = rolled_back_lr_scale(stability.lr_scale, hp.collapse_lr_factor, hp.collapse_lr_floor)
        stability.rollbacks += 1
        if any(not self._lost_completion(e, best.completion) for e in collapsed):
            stability.slow_rollbacks += 1
        stability.floor = version
        self.watch.restart(version)

    def _lost_completion(self, evaluation: dict, best_completion: float) -> bool:
        """The evaluation collapsed by its completion (``is_collapsed``), whatever its pace."""
        hp = self.hp
        return is_collapsed(evaluation["completion_rate"], best_completion, hp.collapse_min_best, hp.collapse_drop)

    def message(self, best: BestEvaluation, collapsed: list[dict], version: int, lr: tuple[float, float]) -> str:
        """The rollback's log line: what collapsed against what, and the learning rate before and after."""
        versions = ", v".join(str(e["version"]) for e in collapsed)
        completions = ", ".join(f"{e['completion_rate']:.2f}" for e in collapsed)
        threshold = best.completion * (1.0 - self.hp.collapse_drop)
        slower = self._slowdown_words(collapsed, best.mean_lap_s)
        return (
            f"collapse guard: v{versions} completed {completions} of their evaluation trials against best "
            f"v{best.version}'s {best.completion:.2f} (collapsed at <= {threshold:.2f}){slower}; rolled back to "
            f"v{best.version}'s weights and optimizer as v{version}, learning rate {lr[0]:.3g} -> {lr[1]:.3g} "
            f"(collapses {self.stability.collapses}, rollbacks {self.stability.rollbacks})"
        )

    def _slowdown_words(self, collapsed: list[dict], best_lap: float | None) -> str:
        """The mean laps of the collapsed evaluations against the best's, for the rollback's log line (when the
        guard watches lap times)."""
        if self.hp.collapse_slowdown is None or best_lap is None:
            return ""
        laps = ", ".join("-" if e.get("mean_lap_s") is None else f"{e['mean_lap_s']:.2f}" for e in collapsed)
        limit = best_lap * (1.0 + self.hp.collapse_slowdown)
        return f", mean laps {laps} s against its {best_lap:.2f} s (slower than {limit:.2f} s)"
