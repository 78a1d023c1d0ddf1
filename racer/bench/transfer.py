"""``racer bench transfer``: the DeepRacer paper's Table II in simulation.

Balaji et al. (Table II) train policies with one change each, pick each one's checkpoint by robust evaluation and
drive it 6 times in each of five real conditions it never trained in. This bench does the same with racer's parts:

- **Tracks** (:data:`TRACKS`, ``--tracks``): racer's own, so that it runs offline. A, where every row is driven,
  is ``racer_bends``, on which no row trains; B is ``racer_loop`` (the default track), C ``racer_wide`` (wider and
  longer), D ``racer_loop_cw`` (B mirrored: B+D is one shape driven both ways, less of a mix than the paper's two
  tracks).
- **The "real" world**: track A driven by another car than the training car (``--car``, default the
  ``deepracer-gazebo`` preset: 0.5 s of steering lag, μ 0.44) in the paper's five conditions
  (:data:`CONDITIONS`: ``speed-0.5``, ``speed-1.0``, ``sunlight``, ``no-barriers``, ``tape``;
  ``common/conditions.py``), 3 starts spread round the lap in each direction = 6 trials, no action noise.
- **Rows** (:data:`ROWS`): each ``racer train`` from scratch on DeepRacer's default reward, action space and
  hyperparameters for ``--minutes`` with the evaluator beside it (robust evaluation: 6 starts, 10 % action noise);
  the checkpoint driven is the run's ``best``, as the paper picks by robust evaluation. "Throttle = X" scales the
  default action space's speeds (0.5, 1 m/s) by X (the paper's default throttle is 1 m/s).
- **Resume**: each finished row is written to ``OUT/rows/<name>.json``; a rerun skips those (``--fresh`` ignores
  them). ``--rows`` picks a subset.

The paper's totals (:attr:`TransferRow.paper_total`) are those quoted in racer's issue 51 (the paper's table was
not at hand in text form): rows whose total it does not give have ``None``, and "Default 12–16" is the range over
the default rows, ranked by its middle. The JSON's ``spearman`` is the rank correlation of racer's totals with the
paper's over the rows that have one.
"""

from __future__ import annotations

import json
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from rich.table import Table

from common.action_space import default_action_space
from common.car_calibration import load_car
from common.conditions import apply_condition, load_condition
from common.config import RunConfig, WorkerEnv
from common.errors import OptionError
from model_store import LocalStore, RunStore
from racer.bench import Report

TRACKS: dict[str, str] = {"A": "racer_bends", "B": "racer_loop", "C": "racer_wide", "D": "racer_loop_cw"}
"""The paper's tracks as racer's own: A is where every row is driven (and none trains)."""
CONDITIONS = ("speed-0.5", "speed-1.0", "sunlight", "no-barriers", "tape")
"""The paper's five real conditions, in its column order."""
TRIALS_PER_DIRECTION = 3
"""Starts per direction on track A: 6 trials per condition, as the paper drove each."""
REAL_CAR = "deepracer-gazebo"
"""The car of the "real" world: not the training car."""
ROBUST_STARTS = 6
"""Robust-evaluation starts of each checkpoint while training (the track's direction only, 10 % action noise)."""
WORKERS = 2
"""Rollout workers per row."""

_ALL_AUG = {"color_prob": 0.5, "translate_prob": 0.5, "shadow_prob": 0.5, "sharpen_prob": 0.5, "salt_pepper_prob": 0.5}


@dataclass(frozen=True)
class TransferRow:
    """One row of Table II: where it trains, what it changes, and the paper's total."""

    name: str
    tracks: tuple[str, ...]
    """Training tracks by the paper's letters (two: half the workers on each)."""
    paper_total: float | None
    """The paper's total out of 30 (a range's middle), None where racer's issue does not quote it."""
    policy: dict[str, Any] = field(default_factory=dict)
    """PolicyConfig fields (dropout, batch_norm, l2)."""
    hyperparams: dict[str, Any] = field(default_factory=dict)
    """Hyperparameters fields (beta_entropy)."""
    augment: dict[str, float] = field(default_factory=dict)
    """AugmentationConfig fields."""
    throttle: float = 1.0
    """The default action space's speeds × this."""


ROWS: tuple[TransferRow, ...] = (
    TransferRow("default-B", ("B",), 14.0),
    TransferRow("default-C", ("C",), 14.0),
    TransferRow("default-D", ("D",), 14.0),
    TransferRow("l2-B", ("B",), None, policy={"l2": 2e-5}),
    TransferRow("dropout-B", ("B",), 23.0, policy={"dropout": 0.3}),
    TransferRow("batchnorm-B", ("B",), None, policy={"batch_norm": True}),
    TransferRow("throttle-0.33-B", ("B",), 4.0, throttle=0.33),
    TransferRow("throttle-1.67-B", ("B",), 23.0, throttle=1.67),
    TransferRow("throttle-2.33-B", ("B",), 24.0, throttle=2.33),
    TransferRow("default-BD", ("B", "D"), 14.0),
    TransferRow("color-BD", ("B", "D"), 26.0, augment={"color_prob": 0.5}),
    TransferRow("translation-BD", ("B", "D"), 22.0, augment={"translate_prob": 0.5}),
    TransferRow("shadow-BD", ("B", "D"), 18.0, augment={"shadow_prob": 0.5}),
    TransferRow("sharpen-BD", ("B", "D"), None, augment={"sharpen_prob": 0.5}),
    TransferRow("pepper-BD", ("B", "D"), 16.0, augment={"salt_pepper_prob": 0.5}),
    TransferRow("all-aug-BD", ("B", "D"), 18.0, augment=_ALL_AUG),
    TransferRow(
        "best-C",
        ("C",),
        27.0,
        policy={"l2": 2e-5, "dropout": 0.3},
        hyperparams={"beta_entropy": 0.001},
        augment={"color_prob": 0.5},
        throttle=2.33,
    ),
)
"""Table II's rows, in its order."""


@dataclass(frozen=True)
class TransferSettings:
    """What ``racer bench transfer`` runs."""

    rows: tuple[TransferRow, ...]
    minutes: float
    out: Path
    tracks: dict[str, str] = field(default_factory=lambda: dict(TRACKS))
    car: str = REAL_CAR
    workers: int = WORKERS
    fresh: bool = False


def pick_rows(names: list[str] | None) -> tuple[TransferRow, ...]:
    """The rows named (all of them for None); OptionError naming an unknown one."""
    if not names:
        return ROWS
    known = {r.name: r for r in ROWS}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise OptionError(f"--rows {', '.join(unknown)}: not a row of Table II ({', '.join(known)})")
    return tuple(known[n] for n in names)


def parse_tracks(spec: str | None) -> dict[str, str]:
    """``--tracks A=name,B=name,…`` over :data:`TRACKS`; OptionError for another letter or a track that does
    not load."""
    from sim.track import load_track

    tracks = dict(TRACKS)
    for part in [p for p in (spec or "").split(",") if p.strip()]:
        letter, _, name = part.partition("=")
        if letter.strip() not in TRACKS or not name.strip():
            raise OptionError(f"--tracks {part!r}: expected A=TRACK, B=TRACK, C=TRACK or D=TRACK")
        tracks[letter.strip()] = name.strip()
    for name in tracks.values():
        load_track(name)
    if len(set(tracks.values())) != len(tracks):
        raise OptionError(f"--tracks: the four tracks must be distinct (got {tracks})")
    return tracks


def row_run(row: TransferRow, tracks: dict[str, str], folder: Path) -> tuple[RunConfig, dict[str, bytes]]:
    """The row's run: DeepRacer's defaults with the row's one change, on its training track(s)."""
    from racer.runconfig import build_run

    options: dict[str, Any] = {"track": tracks[row.tracks[0]]}
    if row.throttle != 1.0:
        space = default_action_space()
        scaled = [a.model_copy(update={"speed": round(a.speed * row.throttle, 3)}) for a in space.action_space]
        path = folder / "model_metadata.json"
        path.write_text(space.model_copy(update={"action_space": scaled}).to_json())
        options["action_space"] = str(path)
    if row.hyperparams:
        path = folder / "hyperparameters.json"
        path.write_text(json.dumps(row.hyperparams))
        options["hyperparams"] = str(path)
    if row.augment:
        path = folder / "randomization.json"
        path.write_text(json.dumps({"augment": row.augment}))
        options["randomization"] = str(path)
    run, files = build_run(f"transfer-{row.name}", **options)
    update: dict[str, Any] = {"policy": run.policy.model_copy(update=row.policy)}
    if len(row.tracks) > 1:  # half the workers on each training track
        update["worker_envs"] = [WorkerEnv(track=tracks[t]) for t in row.tracks]
    return run.model_copy(update=update), files


def drive_conditions(runs: RunStore, run: RunConfig, settings: TransferSettings, folder: Path) -> dict[str, Any]:
    """The run's best checkpoint (latest where none was judged) driven on track A by the real car in each
    condition: laps out of the trials, and the mean progress."""
    from model_store.localize import localize_env
    from trainer.evaluator import EvalSettings, evaluate_checkpoint

    version = "best" if runs.pointer(run.run_id, "best") else "latest"
    env = localize_env(run, runs, folder).model_copy(update={"car": load_car(settings.car), "worker_envs": []})
    trials = EvalSettings(
        episodes=TRIALS_PER_DIRECTION, both_directions=True, action_noise=0.0, tracks=[settings.tracks["A"]]
    )
    cells = {}
    for name in CONDITIONS:
        record = evaluate_checkpoint(runs, run, apply_condition(env, load_condition(name)), version, trials)
        cells[name] = {"laps": len(record["lap_times_s"]), "mean_progress": round(record["mean_progress"], 1)}
    return {"version": record["version"], "checkpoint": version, "conditions": cells}


def changes(row: TransferRow) -> dict[str, Any]:
    """What the row changes from DeepRacer's defaults (nothing for a default row)."""
    fields = {k: v for k, v in asdict(row).items() if k in ("policy", "hyperparams", "augment") and v}
    return fields | ({"throttle": row.throttle} if row.throttle != 1.0 else {})


def run_row(row: TransferRow, settings: TransferSettings) -> dict[str, Any]:
    """Train one row for the budget, then drive its chosen checkpoint in the five conditions."""
    from racer.bench.race import race_curve, train_from_scratch

    t0 = time.time()
    with tempfile.TemporaryDirectory(prefix="racer-transfer-") as tmp:
        run, files = row_run(row, settings.tracks, Path(tmp))
        store = Path(tmp, "store")
        curve, guard = train_from_scratch(
            run,
            files,
            workers=settings.workers,
            minutes=settings.minutes,
            eval_episodes=ROBUST_STARTS,
            read_curve=race_curve,
            store_dir=store,
        )
        driven = drive_conditions(RunStore(LocalStore(store)), run, settings, Path(tmp))
    laps = {c: driven["conditions"][c]["laps"] for c in CONDITIONS}
    robust = [p for p in curve if p["completion"] >= 1.0]
    return {
        "name": row.name,
        "track": "+".join(row.tracks),
        "training_tracks": [settings.tracks[t] for t in row.tracks],
        "changes": changes(row),
        "laps": laps,
        "total": sum(laps.values()),
        "out_of": len(CONDITIONS) * 2 * TRIALS_PER_DIRECTION,
        "paper_total": row.paper_total,
        "progress": {c: driven["conditions"][c]["mean_progress"] for c in CONDITIONS},
        "checkpoint": {"version": driven["version"], "chosen_by": driven["checkpoint"]},
        "checkpoints_evaluated": len(curve),
        "robust_checkpoints": len(robust),
        "time_to_robust_s": robust[0]["time_s"] if robust else None,
        **guard,
        "minutes": settings.minutes,
        "seconds": round(time.time() - t0, 1),
    }


def spearman(rows: list[dict]) -> float | None:
    """Rank correlation of racer's totals with the paper's over the rows that have one (None under 3 rows)."""
    from scipy.stats import spearmanr

    pairs = [(r["total"], r["paper_total"]) for r in rows if r["paper_total"] is not None]
    if len(pairs) < 3:
        return None
    rho = spearmanr([p[0] for p in pairs], [p[1] for p in pairs]).statistic
    return None if rho != rho else round(float(rho), 3)  # NaN when one side has no spread


def bench_transfer(
    settings: TransferSettings,
    progress: Callable[[str], None] = print,
    train: Callable[[TransferRow, TransferSettings], dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Every row of ``settings``, resuming from ``settings.out``; the table as JSON. ``train`` makes one row's
    result (default :func:`run_row`: training and driving it)."""
    train = train or run_row
    done_dir = settings.out / "rows"
    done_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for row in settings.rows:
        path = done_dir / f"{row.name}.json"
        if path.exists() and not settings.fresh:
            rows.append(json.loads(path.read_text()))
            progress(f"{row.name}: done before ({path})")
            continue
        progress(f"{row.name}: training {settings.minutes:g} min on {', '.join(row.tracks)}")
        result = train(row, settings)
        path.write_text(json.dumps(result, indent=1))
        rows.append(result)
        progress(f"{row.name}: {result['total']}/{result['out_of']} ({result['laps']})")
    ranked = sorted(rows, key=lambda r: -r["total"])
    best = next((r for r in rows if r["name"] == "best-C"), None)
    return {
        "tracks": settings.tracks,
        "car": settings.car,
        "conditions": list(CONDITIONS),
        "trials_per_condition": 2 * TRIALS_PER_DIRECTION,
        "minutes_per_row": settings.minutes,
        "rows": rows,
        "spearman": spearman(rows),
        "best_combination_rank": ranked.index(best) + 1 if best else None,
    }


def table(result: dict[str, Any]) -> Table:
    """The paper's layout: rows × the five conditions (laps out of 6), racer's total and the paper's."""
    out = Table("row", "track", *result["conditions"], "total", "paper")
    for r in result["rows"]:
        paper = "-" if r["paper_total"] is None else f"{r['paper_total']:g}"
        cells = [str(r["laps"][c]) for c in result["conditions"]]
        out.add_row(r["name"], r["track"], *cells, f"{r['total']}/{r['out_of']}", paper)
    return out


def plot(result: dict[str, Any], png: Path) -> Path:
    """Bars of racer's totals beside the paper's, row by row."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    x = range(len(rows))
    fig, ax = plt.subplots(figsize=(max(6, 0.6 * len(rows)), 4))
    ax.bar([i - 0.2 for i in x], [r["total"] for r in rows], 0.4, label="racer (simulation)")
    paper = [r["paper_total"] or 0 for r in rows]
    ax.bar([i + 0.2 for i in x], paper, 0.4, label="paper (real car; 0 = not quoted)")
    ax.set_xticks(list(x), [r["name"] for r in rows], rotation=60, ha="right")
    ax.set_ylabel("laps out of 30")
    ax.set_title(f"Table II in simulation: Spearman {result['spearman']}")
    ax.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=100)
    plt.close(fig)
    return png


def command_line(settings: TransferSettings) -> str:
    """The ``racer bench transfer`` command that makes this table (the output files aside)."""
    parts = ["racer bench transfer", f"--minutes {settings.minutes:g}"]
    if settings.rows != ROWS:
        parts.append("--rows " + ",".join(r.name for r in settings.rows))
    if settings.tracks != TRACKS:
        parts.append("--tracks " + ",".join(f"{k}={v}" for k, v in settings.tracks.items()))
    if settings.car != REAL_CAR:
        parts.append(f"--car {settings.car}")
    return " ".join(parts)


def command(
    rows: list[str] | None,
    minutes: float,
    out: Path,
    *,
    tracks: str | None = None,
    car: str | None = None,
    fresh: bool = False,
    png: Path | None = None,
) -> Report:
    """``racer bench transfer``: check the options, run (or resume) the rows, show the table."""
    car = car or REAL_CAR
    load_car(car)  # a bad car or track fails now, not after the first row's training
    settings = TransferSettings(pick_rows(rows), minutes, out, parse_tracks(tracks), car, fresh=fresh)
    result = {"command": command_line(settings), **bench_transfer(settings)}
    if png is not None:
        plot(result, png)
    rank = result["best_combination_rank"]
    line = f"Spearman with the paper's totals: {result['spearman']}; the best combination ranks {rank}"
    return Report(result, [table(result), line])
