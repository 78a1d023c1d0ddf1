"""``racer import``: a DeepRacer model (the car's ``.tar.gz``, a simulator model folder, or that folder on S3) as a
new racer run whose version 0 holds its weights, so that ``racer eval`` scores it and ``racer train --pretrained``
keeps training it.

What is read, from the folder's top or where DRfC and DeepRacer on AWS put it (``deploy/deepracer_format.py``):

* ``model_metadata.json`` (top, else ``model/``): the action space, sensors and ``neural_network``, checked as
  ``racer train`` checks its action space file (``common.action_space.load_action_space``). A network racer does
  not build, a sensor list it does not drive, or SAC is one line naming the file.
* The weights: the checkpoint ``model/.coach_checkpoint`` names (its ``.index`` and ``.data-*``), else the one
  ``.pb`` frozen graph (the car's archive holds only that). ``network_1``'s embedders, middleware and policy head
  become racer's trunk and policy head (``deploy/deepracer_graph.py: load_simapp_weights``). racer has one trunk for
  both heads, rl_coach two networks: the value head is ``network_0``'s when ``network_0``'s trunk is identical (a
  model racer exported), else racer's freshly initialised one (a frozen graph has no value head at all): PPO then
  relearns the value while the policy starts where DeepRacer left it.
* ``reward_function.py`` (top), ``hyperparameters.json`` (top, else ``ip/``) and ``training_params.yaml``'s
  ``WORLD_NAME`` as the run's track, each replaced by racer's default when absent (the car's archive has none of
  them), with a note saying so.
"""

from __future__ import annotations

import tarfile
import tempfile
from pathlib import Path
from typing import Any, Protocol

import yaml

from common.action_space import load_action_space
from common.config import RunConfig, network_from_metadata
from common.defaults import DEFAULT_TRACK
from common.errors import OptionError
from common.policy import action_space_spec, build_policy
from common.sensors import observation_spec
from common.weights import acting_to_bytes, checkpoint_to_bytes
from deploy.deepracer_graph import (
    FRAME_SHAPE,
    SCOPE,
    DeepRacerModelError,
    checkpoint_variables,
    export_problem,
    frozen_constants,
    load_simapp_weights,
    tensorflow,
)
from model_store import RunStore


def _materialize(source: str, tmp: Path, s3_endpoint: str | None) -> Path:
    """The model's folder on disk: ``source`` itself, its unpacked archive, or its S3 prefix downloaded."""
    if source.startswith("s3://"):
        from model_store import open_store

        store = open_store(source, s3_endpoint)
        found = False
        for info in store.list(""):
            (tmp / info.key).parent.mkdir(parents=True, exist_ok=True)
            (tmp / info.key).write_bytes(store.get(info.key))
            found = True
        if not found:
            raise DeepRacerModelError(f"{source}: no files under this prefix")
        return tmp
    path = Path(source)
    if path.is_dir():
        return path
    if not path.is_file():
        raise FileNotFoundError(f"{source}: no such file or folder")
    if not path.name.endswith((".tar.gz", ".tgz", ".tar")):
        raise DeepRacerModelError(f"{source}: give a model folder, a .tar.gz or an s3://bucket/prefix")
    try:
        with tarfile.open(path) as tar:
            tar.extractall(tmp, filter="data")  # refuses absolute paths, links out of tmp and devices
    except (tarfile.TarError, OSError) as exc:
        raise DeepRacerModelError(f"{source}: not a readable tar archive ({exc})") from None
    return tmp


def _first(folder: Path, *names: str) -> Path | None:
    """The first of ``names`` (relative paths) that is a file in ``folder``."""
    return next((folder / n for n in names if (folder / n).is_file()), None)


def _weights(folder: Path, source: str) -> tuple[dict[str, Any], str]:
    """The model's tensors by name and where they came from: the checkpoint .coach_checkpoint names, else the one
    .pb file."""
    state = folder / "model" / ".coach_checkpoint"
    if state.is_file():
        name = state.read_text().strip()
        prefix = folder / "model" / name
        if not Path(f"{prefix}.index").is_file():
            raise DeepRacerModelError(f"{source}: model/.coach_checkpoint names {name!r}, but {name}.index is missing")
        return checkpoint_variables(str(prefix), f"{source}: model/{name}"), f"model/{name}"
    pbs = sorted(p for p in folder.rglob("*.pb") if p.is_file())
    if len(pbs) != 1:
        raise DeepRacerModelError(
            f"{source}: no model/.coach_checkpoint and {len(pbs)} .pb files; give a model with a checkpoint or "
            "exactly one frozen graph"
        )
    rel = str(pbs[0].relative_to(folder))
    return frozen_constants(pbs[0].read_bytes(), f"{source}: {rel}"), rel


def _track(folder: Path, notes: list[str]) -> str:
    """training_params.yaml's WORLD_NAME if racer has that track, else racer's default (with a note)."""
    from sim.track import load_track

    params_path = _first(folder, "training_params.yaml")
    world = None
    if params_path:
        try:
            world = (yaml.safe_load(params_path.read_text()) or {}).get("WORLD_NAME")
        except yaml.YAMLError:
            notes.append("training_params.yaml does not parse: using racer's default track")
    if not world:
        notes.append(f"no track given (training_params.yaml WORLD_NAME): the run's track is {DEFAULT_TRACK}")
        return DEFAULT_TRACK
    try:
        load_track(str(world))
    except Exception:  # any failure to load means racer lacks the track; say so and go on with the default
        notes.append(f"racer has no track {world!r}: the run's track is {DEFAULT_TRACK}")
        return DEFAULT_TRACK
    return str(world)


class BuildRun(Protocol):
    """How a run is built from a user's files (``racer.runconfig.build_run``, passed in by the CLI: ``deploy``
    imports nothing from ``racer``)."""

    def __call__(
        self, run_id: str, *, notes: list[str] | None = None, **files: str | None
    ) -> tuple[RunConfig, dict[str, bytes]]: ...


def import_model(
    runs: RunStore, source: str, run_id: str, s3_endpoint: str | None = None, *, build_run: BuildRun
) -> dict[str, Any]:
    """Read the DeepRacer model at ``source`` into a new run ``run_id`` of ``runs`` (version 0), its files checked
    and its config made by ``build_run``; return what was read and the notes on what took racer's defaults."""
    tensorflow("racer import")  # fail first, in one line, without the extra
    if runs.newest_whole(run_id) is not None:
        raise OptionError(f"run {run_id!r} already exists in {runs.store.uri}: choose another --run-id")
    notes: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = _materialize(source, Path(tmp), s3_endpoint)
        metadata_path = _first(folder, "model_metadata.json", "model/model_metadata.json")
        if metadata_path is None:
            raise DeepRacerModelError(f"{source}: no model_metadata.json (at the top or in model/)")
        actions = load_action_space(metadata_path)
        try:
            network_from_metadata(actions.neural_network)
        except ValueError as exc:
            raise DeepRacerModelError(f"{source}: model_metadata.json: {exc}") from None
        reward = _first(folder, "reward_function.py")
        hyperparams = _first(folder, "hyperparameters.json", "ip/hyperparameters.json")
        notes += [f"no {n}: racer's default is used" for n, p in (("reward_function.py", reward),) if p is None]
        notes += ["no hyperparameters.json: racer's defaults are used"] if hyperparams is None else []
        track = _track(folder, notes)
        run, files = build_run(
            run_id,
            track=track,
            reward_fn=str(reward) if reward else None,
            action_space=str(metadata_path),
            hyperparams=str(hyperparams) if hyperparams else None,
            notes=notes,
        )
        spec = observation_spec(actions.sensor, run.hyperparams.stack_size)
        model = build_policy(spec.camera_shape(FRAME_SHAPE), action_space_spec(actions), run.policy, actions.sensor)
        problem = export_problem(model)
        if problem:
            raise DeepRacerModelError(f"{source}: racer cannot hold this model: {problem}")
        arrays, weights_from = _weights(folder, source)
        value_loaded = load_simapp_weights(model, arrays, f"{source}: {weights_from}")
    if not value_loaded:
        notes.append("the value head starts fresh (network_0 differs from network_1, or the model has no value head)")
    if model.action_kind == "continuous" and f"{SCOPE}/network_1/ppo_head_0/policy_log_std" not in arrays:
        notes.append("the frozen graph has no policy_log_std: the Gaussian's spread starts at racer's initial one")
    for name, data in files.items():
        runs.write_file(run_id, name, data)
        # The copies the trainer keeps for deepracer-utils (trainer/checkpoints.py: Checkpoints.write_run_files).
        mirror = {"model_metadata.json": "model/", "hyperparameters.json": "ip/"}.get(name)
        if mirror:
            runs.write_file(run_id, mirror + name, data)
    runs.write_config(run)
    state = model.state_dict()
    meta = runs.save_checkpoint(
        run_id,
        0,
        checkpoint_to_bytes(state),
        {"env_steps": 0, "imported_from": source, "weights": weights_from},
        acting=acting_to_bytes(state),
    )
    runs.set_pointer(run_id, "best", 0)  # the one checkpoint: what racer eval and racer export take by default
    return {
        "run_id": run_id,
        "version": 0,
        "source": source,
        "weights": weights_from,
        "value_head": "loaded" if value_loaded else "fresh",
        "track": run.env.track,
        "notes": notes,
        "size_bytes": meta["size_bytes"],
    }
