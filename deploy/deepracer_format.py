"""``racer export --format deepracer-car | deepracer-sim``: a racer checkpoint as the files DeepRacer's car and
DeepRacer's simulators load, and the checks those loaders make, written from their code.

The car (``deepracer-car``): a ``.tar.gz`` uploaded in the car's console. aws-deepracer-webserver-pkg
``webserver_pkg/models.py: model_file_upload`` takes only names ending ``.tar.gz``; aws-deepracer-systems-pkg
``model_loader_node.py: extract_archive`` unpacks it, ``get_model_list`` walks every folder for ``.pb`` files and
``transfer_models`` ignores an archive with none or with more than one; ``model_install_state.py`` copies that file
to ``artifacts/<name>/model.pb`` and reads ``model_metadata.json`` from the archive's top folder (``os.path.join(
self.temp_directory, MODEL_METADATA_NAME)``), its ``sensor`` (``model_metadata_file_utils.get_sensors``: names of
``SensorInputKeys``), ``training_algorithm`` (``clipped_ppo`` or ``sac``) and ``lidar_config``; the model optimizer
(aws-deepracer-model-optimizer-pkg ``model_optimizer_node.py: convert_to_mo_cli``) then converts it with the input
names of ``constants.py: NETWORK_INPUT_FORMAT_MAPPING`` and shapes [1, 120, 160, channels] or [1, lidar values].
The archive racer writes is the simapp's model output folder (``/opt/ml/model``: ``agent/model.pb``,
``tensorflow_model.py: copy_best_frozen_graph_to_sm_output_dir``) plus ``model_metadata.json`` at the top, as
DRfC's ``scripts/upload/upload-car.sh`` tars it.

The simulator (``deepracer-sim``): the folder DRfC's ``scripts/upload/upload-model.sh`` uploads and DeepRacer on
AWS imports (aws-solutions/deepracer-on-aws ``source/docs/import/README.md``; ``ImportModel/constants.ts:
REQUIRED_FILES_FOR_IMPORT``; ``import-workflow/utils/ImportHelper.ts``)::

    model/.coach_checkpoint                 the checkpoint's name, "<n>_Step-<steps>.ckpt" (rl_coach checkpoint.py:
                                            CheckpointStateFile; upload-model.sh writes it the same way)
    model/<n>_Step-<steps>.ckpt.index, .data-00000-of-00001, .meta
                                            (multi_agent_graph_manager.py: save_checkpoint's "{}_Step-{}.ckpt")
    model/model_<n>.pb                      the frozen graph (tensorflow_model.py: write_frozen_graph)
    model/model_metadata.json, model/deepracer_checkpoints.json
                                            (upload-model.sh: copies the one, writes the other's best and last)
    model_metadata.json, reward_function.py, training_params.yaml
                                            (upload-model.sh's uploads; README.md's required root files)
    ip/hyperparameters.json, hyperparameters.json
                                            (upload-model.sh and ImportHelper.ts: ip/; the README lists it at the
                                            root, and the website's check looks for the name anywhere)

``--upload s3://bucket/prefix`` puts that folder's files under the prefix with the same relative keys, as
upload-model.sh lays them out.
"""

from __future__ import annotations

import io
import json
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from common.action_space import ActionSpace
from common.policy import ActorCritic, load_policy
from deploy.deepracer_graph import (
    FRAME_SHAPE,
    DeepRacerModelError,
    SimappSession,
    input_node,
    layout_of,
    simapp_weights,
)
from model_store import RunStore

CAR_MODEL_PATH = "agent/model.pb"
"""Where the frozen graph goes in the car's archive (the simapp's ``/opt/ml/model/agent/model.pb``)."""
CAR_SENSORS = ("observation", "LIDAR", "SECTOR_LIDAR", "LEFT_CAMERA", "FRONT_FACING_CAMERA", "STEREO_CAMERAS")
"""The car's sensor names (webserver-pkg ``constants.py: SensorInputKeys``; systems-pkg the same)."""
CAR_ALGORITHMS = ("clipped_ppo", "sac")
"""``training_algorithm`` values the car accepts (webserver-pkg ``constants.py: TrainingAlgorithms``)."""
SIM_REQUIRED = ("model_metadata.json", "reward_function.py", "training_params.yaml", "hyperparameters.json")
"""DeepRacer on AWS's ``REQUIRED_FILES_FOR_IMPORT`` (website ``pages/ImportModel/constants.ts``)."""
SIM_MAX_BYTES = 1024**3
"""DeepRacer on AWS's ``MAX_FOLDER_SIZE`` (1 GB)."""


def _load(runs: RunStore, run_id: str, checkpoint: str | int) -> tuple[ActorCritic, dict[str, Any], ActionSpace]:
    """The checkpoint's network (checked exportable), its metadata and the run's action space."""
    actions = ActionSpace.model_validate_json(runs.read_file(run_id, "model_metadata.json"))
    model, meta = load_policy(runs, run_id, actions, checkpoint, frame=FRAME_SHAPE)
    layout_of(model)  # refuses, in one line, what DeepRacer's networks cannot hold
    return model, meta, actions


def car_metadata(actions: ActionSpace) -> bytes:
    """model_metadata.json for the car: the run's, with ``training_algorithm`` clipped_ppo (racer's PPO)."""
    return actions.model_copy(update={"training_algorithm": "clipped_ppo"}).to_json().encode()


def export_car(runs: RunStore, run_id: str, checkpoint: str | int, out: str | Path) -> dict[str, Any]:
    """Write the car's ``.tar.gz`` (``agent/model.pb`` and ``model_metadata.json``); return what was written."""
    out = Path(out)
    if not out.name.endswith(".tar.gz"):
        raise DeepRacerModelError(f"{out}: the car's console takes only a .tar.gz file (webserver models.py)")
    model, meta, actions = _load(runs, run_id, checkpoint)
    session = SimappSession(layout_of(model), simapp_weights(model))
    try:
        pb = session.frozen()
    finally:
        session.close()
    files = {"model_metadata.json": car_metadata(actions), CAR_MODEL_PATH: pb}
    out.parent.mkdir(parents=True, exist_ok=True)
    with tarfile.open(out, "w:gz") as tar:
        for name, data in files.items():
            info = tarfile.TarInfo(name)
            info.size, info.mtime = len(data), int(time.time())
            tar.addfile(info, io.BytesIO(data))
    problems = car_archive_problems(out)
    if problems:  # racer's own bug if it happens: the layout is ours
        raise AssertionError(f"{out}: {'; '.join(problems)}")
    return {
        "run_id": run_id,
        "version": int(meta["version"]),
        "model": str(out),
        "inputs": [input_node(s) for s in layout_of(model).sensors],
    }


def checkpoint_name(version: int, env_steps: int) -> str:
    """The simapp's checkpoint name for racer's version and env steps: ``<n>_Step-<steps>.ckpt``."""
    return f"{version}_Step-{env_steps}.ckpt"


def training_params(runs: RunStore, run_id: str, prefix: str) -> bytes:
    """training_params.yaml: the keys DRfC's ``scripts/upload/prepare-config.py`` writes (its defaults where racer
    has no counterpart: the car's shell, colour and name), with the run's track and race type and S3 keys under
    ``prefix``."""
    run = runs.read_config(run_id)
    params = {
        "AWS_REGION": "us-east-1",
        "JOB_TYPE": "TRAINING",
        "METRICS_S3_BUCKET": "bucket",
        "METRICS_S3_OBJECT_KEY": f"{prefix}/TrainingMetrics.json",
        "MODEL_METADATA_FILE_S3_KEY": f"{prefix}/model/model_metadata.json",
        "REWARD_FILE_S3_KEY": f"{prefix}/reward_function.py",
        "SAGEMAKER_SHARED_S3_BUCKET": "bucket",
        "SAGEMAKER_SHARED_S3_PREFIX": prefix,
        "BODY_SHELL_TYPE": "deepracer",
        "CAR_COLOR": "Red",
        "CAR_NAME": "racer",
        "RACE_TYPE": str(run.env.race.race_type),
        "WORLD_NAME": Path(run.env.track).stem,
        "DISPLAY_NAME": run_id,
        "RACER_NAME": run_id,
        "ALTERNATE_DRIVING_DIRECTION": "false",
        "CHANGE_START_POSITION": "true",
        "ROUND_ROBIN_ADVANCE_DIST": "0.05",
        "START_POSITION_OFFSET": "0.00",
        "ENABLE_DOMAIN_RANDOMIZATION": "false",
        "MIN_EVAL_TRIALS": "5",
    }
    return yaml.safe_dump(params, default_flow_style=False, explicit_start=True).encode()


def sim_files(runs: RunStore, run_id: str, checkpoint: str | int, prefix: str = "racer-model") -> dict[str, bytes]:
    """The deepracer-sim folder's files by relative path (module docstring)."""
    model, meta, actions = _load(runs, run_id, checkpoint)
    version, steps = int(meta["version"]), int(meta.get("env_steps") or 0)
    ckpt = checkpoint_name(version, steps)
    session = SimappSession(layout_of(model), simapp_weights(model))
    files: dict[str, bytes] = {}
    try:
        files[f"model/model_{version}.pb"] = session.frozen()
        with tempfile.TemporaryDirectory() as tmp:
            session.save_checkpoint(str(Path(tmp) / ckpt))
            for path in sorted(Path(tmp).iterdir()):
                files[f"model/{path.name}"] = path.read_bytes()
    finally:
        session.close()
    metadata = car_metadata(actions)
    entry = {"name": ckpt, "time_stamp": float(meta.get("created") or time.time()), "avg_comp_pct": 0.0}
    hyperparameters = runs.read_file(run_id, "hyperparameters.json")
    files.update(
        {
            "model/.coach_checkpoint": ckpt.encode(),
            "model/model_metadata.json": metadata,
            "model/deepracer_checkpoints.json": json.dumps(
                {"best_checkpoint": entry, "last_checkpoint": entry}, indent=4
            ).encode(),
            "model_metadata.json": metadata,
            "reward_function.py": runs.read_file(run_id, "reward_function.py"),
            "training_params.yaml": training_params(runs, run_id, prefix),
            "hyperparameters.json": hyperparameters,
            "ip/hyperparameters.json": hyperparameters,
        }
    )
    return files


def export_sim(
    runs: RunStore,
    run_id: str,
    checkpoint: str | int,
    out: str | Path,
    upload: str | None = None,
    s3_endpoint: str | None = None,
) -> dict[str, Any]:
    """Write the deepracer-sim folder ``out`` (and, with ``upload`` = ``s3://bucket/prefix``, the same files under
    that prefix); return what was written."""
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise DeepRacerModelError(f"{out}: give a new or empty folder for the deepracer-sim export")
    prefix = upload.removeprefix("s3://").partition("/")[2].strip("/") if upload else "racer-model"
    files = sim_files(runs, run_id, checkpoint, prefix or "racer-model")
    for name, data in files.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(data)
    problems = sim_folder_problems(out)
    if problems:
        raise AssertionError(f"{out}: {'; '.join(problems)}")
    result: dict[str, Any] = {"run_id": run_id, "folder": str(out), "files": sorted(files)}
    if upload:
        from model_store import open_store

        if not upload.startswith("s3://"):
            raise DeepRacerModelError(f"--upload {upload!r}: give an s3://bucket/prefix")
        store = open_store(upload, s3_endpoint)
        for name, data in files.items():
            store.put(name, data)
        result["uploaded"] = upload
    return result


# --- the loaders' checks --------------------------------------------------------------------------------------------


def metadata_problems(metadata: dict[str, Any], where: str) -> list[str]:
    """What the car's loaders refuse in a model_metadata.json (webserver-pkg ``models.py``: ``get_sensors``,
    ``get_training_algorithm``, ``get_action_space_type``, ``validate_action_space``)."""
    problems = []
    sensors = metadata.get("sensor", ["observation"])
    unknown = [s for s in sensors if s not in CAR_SENSORS]
    if unknown:
        problems.append(f"{where}: sensor {unknown[0]!r} is not one the car knows (get_sensors)")
    if metadata.get("training_algorithm", "clipped_ppo") not in CAR_ALGORITHMS:
        problems.append(f"{where}: training_algorithm {metadata.get('training_algorithm')!r} (get_training_algorithm)")
    kind = metadata.get("action_space_type", "discrete")
    space = metadata.get("action_space")
    if kind == "discrete":
        if not isinstance(space, list) or not all("steering_angle" in a and "speed" in a for a in space):
            problems.append(f"{where}: a discrete action needs steering_angle and speed (validate_action_space)")
    elif kind == "continuous":
        ok = isinstance(space, dict) and all(
            isinstance(space.get(k), dict) and space[k].get("high", 0) > space[k].get("low", 0)
            for k in ("steering_angle", "speed")
        )
        if not ok:
            problems.append(f"{where}: continuous ranges need low < high (validate_action_space)")
    else:
        problems.append(f"{where}: action_space_type {kind!r} (get_action_space_type)")
    return problems


def graph_problems(pb: bytes, metadata: dict[str, Any], where: str) -> list[str]:
    """A frozen graph without the inputs the car's model optimizer names for the metadata's sensors
    (``NETWORK_INPUT_FORMAT_MAPPING``, ``INPUT_SHAPE_FORMAT_MAPPING``) or without the simapp's policy output."""
    from deploy.deepracer_graph import POLICY_NODE, tensorflow

    tf = tensorflow("checking a DeepRacer model.pb")
    graph_def = tf.compat.v1.GraphDef()
    graph_def.ParseFromString(pb)
    nodes = {n.name: n for n in graph_def.node}
    problems = []
    channels = {"FRONT_FACING_CAMERA": 1, "observation": 1, "LEFT_CAMERA": 1, "STEREO_CAMERAS": 2}
    lidar = {"LIDAR": 64, "SECTOR_LIDAR": 8}
    for sensor in metadata.get("sensor", ["observation"]):
        node = nodes.get(input_node(sensor))
        if node is None or node.op != "Placeholder":
            problems.append(f"{where}: no placeholder {input_node(sensor)} (model optimizer --input)")
            continue
        dims = [d.size for d in node.attr["shape"].shape.dim]
        want = [-1, *FRAME_SHAPE, channels[sensor]] if sensor in channels else [-1, lidar.get(sensor, -1)]
        if dims != want:
            problems.append(f"{where}: {input_node(sensor)} has shape {dims}, the car feeds {want} (--input_shape)")
    if POLICY_NODE not in nodes:
        problems.append(f"{where}: no output {POLICY_NODE} (simapp FROZEN_HEAD_OUTPUT_GRAPH_FORMAT_MAPPING)")
    return problems


def car_archive_problems(path: str | Path) -> list[str]:
    """Every check the car's upload and loader make on an archive, as one line each (module docstring)."""
    path = Path(path)
    if not path.name.endswith(".tar.gz"):
        return [f"{path.name}: not a .tar.gz (webserver models.py model_file_upload)"]
    with tarfile.open(path, "r:gz") as tar:
        members = {m.name.removeprefix("./"): m for m in tar.getmembers() if m.isfile()}
        pbs = [name for name in members if name.endswith(".pb")]
        if len(pbs) != 1:
            return [f"{path.name}: {len(pbs)} .pb files; the loader takes exactly one (transfer_models)"]
        if "model_metadata.json" not in members:
            return [f"{path.name}: no model_metadata.json at the top (model_install_state.py)"]
        metadata = json.loads(tar.extractfile(members["model_metadata.json"]).read())  # type: ignore[union-attr]
        pb = tar.extractfile(members[pbs[0]]).read()  # type: ignore[union-attr]
    return metadata_problems(metadata, "model_metadata.json") + graph_problems(pb, metadata, pbs[0])


def sim_folder_problems(folder: str | Path) -> list[str]:
    """Every check DRfC's upload and DeepRacer on AWS's import make on a folder, as one line each."""
    folder = Path(folder)
    files = [p for p in folder.rglob("*") if p.is_file()]
    names = {p.name for p in files}
    problems = [f"missing {name} (REQUIRED_FILES_FOR_IMPORT)" for name in SIM_REQUIRED if name not in names]
    if sum(p.stat().st_size for p in files) > SIM_MAX_BYTES:
        problems.append("over 1 GB (MAX_FOLDER_SIZE)")
    for rel in ("model_metadata.json", "reward_function.py", "training_params.yaml", "ip/hyperparameters.json"):
        if not (folder / rel).is_file():
            problems.append(f"missing {rel} (ImportHelper.ts / upload-model.sh)")
    state = folder / "model" / ".coach_checkpoint"
    if not state.is_file():
        return [*problems, "missing model/.coach_checkpoint (README.md)"]
    name = state.read_text().strip()
    n = name.split("_Step")[0]
    if not (n.isdigit() and name.endswith(".ckpt")):
        problems.append(f"model/.coach_checkpoint names {name!r}, not <n>_Step-<steps>.ckpt (save_checkpoint)")
    for ext in (".index", ".data-00000-of-00001", ".meta"):
        if not (folder / "model" / (name + ext)).is_file():
            problems.append(f"missing model/{name}{ext} (README.md: ckpt index, data, meta)")
    if not (folder / "model" / f"model_{n}.pb").is_file():
        problems.append(f"missing model/model_{n}.pb (upload-model.sh)")
    checkpoints = folder / "model" / "deepracer_checkpoints.json"
    if not checkpoints.is_file() or json.loads(checkpoints.read_text())["last_checkpoint"]["name"] != name:
        problems.append("model/deepracer_checkpoints.json does not name the checkpoint (upload-model.sh)")
    metadata = json.loads((folder / "model_metadata.json").read_text()) if "model_metadata.json" in names else {}
    params = yaml.safe_load((folder / "training_params.yaml").read_text()) if "training_params.yaml" in names else {}
    if not (params or {}).get("WORLD_NAME"):
        problems.append("training_params.yaml has no WORLD_NAME (ImportHelper.ts getTrackConfig)")
    if metadata.get("training_algorithm") == "sac" and metadata.get("action_space_type") != "continuous":
        problems.append("SAC needs a continuous action space (README.md: Algorithm mismatch)")
    return problems + metadata_problems(metadata, "model_metadata.json")
