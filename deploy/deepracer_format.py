"""``racer export --format deepracer-car | deepracer-sim``: a racer checkpoint as the files DeepRacer's car and
DeepRacer's simulators load, and the checks those loaders make, written from their code.

Every check below names the upstream ``file:line`` it follows. The line numbers refer to these commits (the local
mirrors under /work/.mirror; paths are relative to each repository's root)::

    name        repository (github.com/...)                       commit    paths below are under
    webserver   aws-deepracer/aws-deepracer-webserver-pkg         43e05a7   webserver_pkg/webserver_pkg/
    systems     aws-deepracer/aws-deepracer-systems-pkg           d0a9b6b   deepracer_systems_pkg/deepracer_systems_pkg/
    ctrl        aws-deepracer/aws-deepracer-ctrl-pkg              30acc1c   ctrl_pkg/src/
    optimizer   aws-deepracer/aws-deepracer-model-optimizer-pkg   d2b4a65   model_optimizer_pkg/model_optimizer_pkg/
    inference   aws-deepracer/aws-deepracer-inference-pkg         36ca404   inference_pkg/src/
    simapp      aws-deepracer-community/deepracer-simapp          01f5f015  bundle/
    DRfC        aws-deepracer-community/deepracer-for-cloud       2eb1a1f   (the repository root)
    DoA         aws-solutions/deepracer-on-aws                    61af778   source/

The car (``deepracer-car``): a ``.tar.gz`` uploaded in the car's console. webserver ``models.py:663-667``
(``model_file_upload``) takes only names ending ``.tar.gz`` and hands the folder to systems
``model_loader_module/model_loader_node.py:709`` (``console_model_action`` -> ``transfer_models``), which unpacks it
(``:385-391``, ``extract_archive``: gunzip, then untar), counts the model files in every folder (``:414-427``,
``get_model_list``; ``:108`` makes the model extension the *string* ``".pb"``, so ``ext not in ".pb"`` at ``:419`` is
a substring test and a file with no extension counts as a model too) and ignores an archive with none (``:576-579``)
or with more than one (``:581-585``). ``model_install_state.py:101-110`` copies that file to
``artifacts/<name>/model.pb`` (``model_loader_config.py:48-49``) and ``:115-123`` copies ``model_metadata.json`` from
the archive's top folder if it is there. Loading the model (webserver ``models.py:524-570``, ``api_load_model``)
reads that file and refuses it at the first failing step: ``sensor`` (``:232-269``, ``get_sensors``: names of
``constants.py:189-199`` ``SensorInputKeys``), ``training_algorithm`` (``:272-304``; ``constants.py:228-232``),
``action_space_type`` (``:307-339``; ``constants.py:256-260``), ``action_space`` (``:342-364``, then
``:194-229`` ``validate_action_space``) and ``lidar_config`` (``:367-420``, ``load_lidar_configuration``). The
systems-pkg reading of the same keys (``model_install_state.py:125-209``) does not run: ``model_loader_config.py:28``
sets ``ENABLE_MODEL_OPTIMIZER = False``. The webserver's request (``models.py:600-616``) goes through ctrl
``ctrl_state.cpp:163-172`` to optimizer ``model_optimizer_node.py:189-218`` (``convert_to_mo_cli``), which names the
graph's inputs with ``constants.py:55-58`` and ``:63-70`` (``INPUT_HEAD_NAME_MAPPING``,
``NETWORK_INPUT_FORMAT_MAPPING``) and shapes them [1, 120, 160, channels] (webserver ``constants.py:118-124``,
optimizer ``constants.py:74-79``) or [1, lidar sectors] (webserver ``models.py:612-613``); inference
``intel_inference_eng.cpp:90-91`` then reads the converted network's first output. The archive racer writes is the
simapp's model output folder (``/opt/ml/model``, simapp
``markov/boto/s3/files/checkpoint_files/tensorflow_model.py:46``: ``agent/model.pb``, ``:329-371``
``copy_best_frozen_graph_to_sm_output_dir``) plus ``model_metadata.json`` at the top, as DRfC
``scripts/upload/upload-car.sh:54-57`` tars it.

The simulator (``deepracer-sim``): the folder DRfC ``scripts/upload/upload-model.sh`` uploads (``:198-227``) and
DeepRacer on AWS imports (DoA ``docs/import/README.md:14-21``; website
``apps/website/src/pages/ImportModel/constants.ts:4-11`` and ``ImportModel.tsx:49-56``; lambda
``libs/lambda/src/import-workflow/utils/ImportHelper.ts:37-168``; then the simapp's validation container,
``apps/infra/lib/constructs/import-workflow/importWorkflow.ts:103``, simapp ``markov/validation_worker.py:141-173``)::

    model/.coach_checkpoint                 the checkpoint's name, "<n>_Step-<steps>.ckpt" (simapp rl_coach
                                            ``rl_coach/rl_coach/checkpoint.py:119,254``; upload-model.sh:200)
    model/<n>_Step-<steps>.ckpt.index, .data-00000-of-00001, .meta
                                            (simapp ``markov/multi_agent_coach/multi_agent_graph_manager.py:642``;
                                            README.md:17; tensorflow_model.py:168-178 fetches them by that name)
    model/model_<n>.pb                      the frozen graph (tensorflow_model.py:389-406; upload-model.sh:192)
    model/model_metadata.json, model/deepracer_checkpoints.json
                                            (upload-model.sh:198 copies the one, :180 and :221 write the other's
                                            best and last; the simapp validates model/model_metadata.json,
                                            ``markov/boto/s3/constants.py:50``)
    model_metadata.json, reward_function.py, training_params.yaml
                                            (upload-model.sh:223-227; README.md:18-20; ImportHelper.ts:38,54,139)
    ip/hyperparameters.json, hyperparameters.json
                                            (upload-model.sh:108,226 and ImportHelper.ts:69: ip/; README.md:21 lists
                                            it at the root, and ImportModel.tsx:55-56 looks for the name anywhere)

``--upload s3://bucket/prefix`` puts that folder's files under the prefix with the same relative keys, as
upload-model.sh lays them out.
"""

from __future__ import annotations

import io
import json
import os
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from common.action_space import ActionSpace
from common.policy import ActorCritic
from common.weights import load_policy
from deploy.deepracer_graph import (
    FRAME_SHAPE,
    POLICY_NODE,
    DeepRacerModelError,
    SimappSession,
    input_node,
    layout_of,
    simapp_weights,
)
from deploy.export import camera_network
from model_store import RunStore

CAR_MODEL_PATH = "agent/model.pb"
"""Where the frozen graph goes in the car's archive (simapp ``tensorflow_model.py:46,371``:
``/opt/ml/model/agent/model.pb``)."""
CAR_SENSORS = ("observation", "LIDAR", "SECTOR_LIDAR", "LEFT_CAMERA", "FRONT_FACING_CAMERA", "STEREO_CAMERAS")
"""The car's sensor names (webserver ``constants.py:189-199`` ``SensorInputKeys``; systems ``constants.py:90-100``)."""
CAR_ALGORITHMS = ("clipped_ppo", "sac")
"""``training_algorithm`` values the car accepts (webserver ``constants.py:228-232`` ``TrainingAlgorithms``)."""
CAR_LIDAR_KEYS = ("num_values", "min_angle", "max_angle", "min_distance", "max_distance", "clipping_distance")
"""``lidar_config`` keys the car reads besides ``num_sectors`` (webserver ``models.py:394-415``; names at
``constants.py:290-296``)."""
CAR_LIDAR_SECTORS = {"LIDAR": 64, "SECTOR_LIDAR": 8}
"""The lidar input's width without a ``lidar_config`` (webserver ``constants.py:318`` and ``:332``)."""
CAR_CHANNELS = {"observation": 1, "LEFT_CAMERA": 1, "FRONT_FACING_CAMERA": 1, "STEREO_CAMERAS": 2}
"""Each camera input's channels (optimizer ``constants.py:74-79`` ``INPUT_CHANNEL_SIZE_MAPPING``)."""
CAR_HEADS = {"clipped_ppo": "main", "sac": "policy"}
"""The network scope the car's inputs sit in (optimizer ``constants.py:55-58`` ``INPUT_HEAD_NAME_MAPPING``)."""
CAR_OUTPUTS = {"clipped_ppo": POLICY_NODE, "sac": "main_level/agent/policy/online/network_0/sac_policy_head_0/policy"}
"""The frozen graph's output per algorithm (simapp ``markov/boto/s3/constants.py:84-87``
``FROZEN_HEAD_OUTPUT_GRAPH_FORMAT_MAPPING`` with agent ``agent``)."""
SIM_REQUIRED = ("model_metadata.json", "reward_function.py", "training_params.yaml", "hyperparameters.json")
"""DeepRacer on AWS's ``REQUIRED_FILES_FOR_IMPORT`` (DoA ``apps/website/src/pages/ImportModel/constants.ts:6-11``)."""
SIM_MAX_BYTES = 1024**3
"""DeepRacer on AWS's ``MAX_FOLDER_SIZE``, 1 GB (DoA ``apps/website/src/pages/ImportModel/constants.ts:4``)."""
SIM_CAMERAS = ("observation", "FRONT_FACING_CAMERA", "LEFT_CAMERA", "STEREO_CAMERAS")
SIM_LIDARS = ("LIDAR", "SECTOR_LIDAR", "DISCRETIZED_SECTOR_LIDAR")
"""The simapp's camera and lidar sensor names (simapp ``markov/boto/s3/files/model_metadata.py:245-246,251``)."""


def _load(runs: RunStore, run_id: str, checkpoint: str | int) -> tuple[ActorCritic, dict[str, Any], ActionSpace]:
    """The checkpoint's network (checked exportable), its metadata and the run's action space."""
    actions = ActionSpace.model_validate_json(runs.read_file(run_id, "model_metadata.json"))
    model, meta = load_policy(runs, run_id, actions, checkpoint, frame=FRAME_SHAPE)
    model = camera_network(model, run_id)
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
    *,
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


def _range_ok(bounds: Any) -> bool:
    """A continuous action range with both ends and low < high (webserver ``models.py:220-227``)."""
    if not isinstance(bounds, dict) or not all(isinstance(bounds.get(k), int | float) for k in ("low", "high")):
        return False
    return bounds["high"] > bounds["low"]


def metadata_problems(metadata: dict[str, Any], where: str) -> list[str]:
    """What the car refuses in a model_metadata.json when the model is loaded (webserver ``models.py:533-570``,
    ``api_load_model``: each step below stops the load with a message)."""
    problems = []
    # models.py:246-258: every name in "sensor" a SensorInputKeys member; models.py:259-263: no key -> observation.
    sensors = metadata.get("sensor", ["observation"])
    if not isinstance(sensors, list):  # set() of it at models.py:247 fails or yields no member
        problems.append(f"{where}: sensor {sensors!r} is not a list of names (get_sensors)")
        sensors = []
    unknown = [s for s in sensors if s not in CAR_SENSORS]
    if unknown:
        problems.append(f"{where}: sensor {unknown[0]!r} is not one the car knows (get_sensors)")
    # models.py:286-293: a TrainingAlgorithms member; models.py:294-298: no key -> clipped_ppo.
    if metadata.get("training_algorithm", "clipped_ppo") not in CAR_ALGORITHMS:
        problems.append(f"{where}: training_algorithm {metadata.get('training_algorithm')!r} (get_training_algorithm)")
    # models.py:321-328: an ActionSpaceTypes member (constants.py:256-260); models.py:329-333: no key -> discrete.
    kind = metadata.get("action_space_type", "discrete")
    space = metadata.get("action_space")
    if "action_space" not in metadata:  # models.py:356-359
        problems.append(f"{where}: no action_space (get_action_space)")
    elif kind == "discrete":  # models.py:207-212: every action has both keys
        if not isinstance(space, list) or not all(
            isinstance(a, dict) and {"steering_angle", "speed"} <= a.keys() for a in space
        ):
            problems.append(f"{where}: a discrete action needs steering_angle and speed (validate_action_space)")
    elif kind == "continuous":  # models.py:213-228: both ranges, each with high and low, high > low
        if not isinstance(space, dict) or not all(_range_ok(space.get(k)) for k in ("steering_angle", "speed")):
            problems.append(f"{where}: continuous ranges need low < high (validate_action_space)")
    else:
        problems.append(f"{where}: action_space_type {kind!r} (get_action_space_type)")
    # models.py:392-415: a lidar model's lidar_config, when given, must hold every key (a KeyError stops the load).
    config = metadata.get("lidar_config")
    if any(s in tuple(CAR_LIDAR_SECTORS) for s in sensors) and config is not None:
        missing = [k for k in (*CAR_LIDAR_KEYS, "num_sectors") if not isinstance(config, dict) or k not in config]
        if missing:
            problems.append(f"{where}: lidar_config has no {missing[0]} (load_lidar_configuration)")
    return problems


def _car_input(sensor: str, algorithm: str) -> str:
    """The graph input the car's model optimizer names for ``sensor`` (optimizer ``model_optimizer_node.py:209-212``
    with ``constants.py:63-70``); for clipped_ppo the same as ``input_node``."""
    return f"main_level/agent/{CAR_HEADS.get(algorithm, 'main')}/online/network_0/{sensor}/{sensor}"


def _lidar_width(metadata: dict[str, Any], sensor: str) -> int:
    """The lidar input's width the car asks for: ``lidar_config.num_sectors`` or the sensor's default (webserver
    ``models.py:382-386,413-415,612-613``)."""
    config = metadata.get("lidar_config")
    if isinstance(config, dict) and isinstance(config.get("num_sectors"), int):
        return config["num_sectors"]
    return CAR_LIDAR_SECTORS.get(sensor, -1)


def graph_problems(pb: bytes, metadata: dict[str, Any], where: str) -> list[str]:
    """A frozen graph without the inputs the car's model optimizer names and shapes for the metadata's sensors
    (optimizer ``model_optimizer_node.py:193-218``) or without the simapp's policy output (simapp
    ``markov/boto/s3/constants.py:84-87``, frozen for it at ``tensorflow_model.py:401-404``)."""
    from deploy.deepracer_graph import tensorflow

    tf = tensorflow("checking a DeepRacer model.pb")
    graph_def = tf.compat.v1.GraphDef()
    graph_def.ParseFromString(pb)
    nodes = {n.name: n for n in graph_def.node}
    problems = []
    algorithm = metadata.get("training_algorithm", "clipped_ppo")
    sensors = metadata.get("sensor", ["observation"])
    # metadata_problems names a "sensor" that is not a list of names
    for sensor in [s for s in sensors if isinstance(s, str)] if isinstance(sensors, list) else []:
        name = _car_input(sensor, algorithm)
        node = nodes.get(name)
        if node is None or node.op != "Placeholder":  # the --input names (model_optimizer_node.py:209-218)
            problems.append(f"{where}: no placeholder {name} (model optimizer --input)")
            continue
        dims = [d.size for d in node.attr["shape"].shape.dim]
        # --input_shape: [1, 120, 160, channels] (model_optimizer_node.py:201-208; webserver constants.py:118-119)
        # or [1, lidar width] (model_optimizer_node.py:195-200); the graph's batch dimension is open.
        want = (
            [-1, *FRAME_SHAPE, CAR_CHANNELS[sensor]] if sensor in CAR_CHANNELS else [-1, _lidar_width(metadata, sensor)]
        )
        if dims != want:
            problems.append(f"{where}: {name} has shape {dims}, the car feeds {want} (--input_shape)")
    output = CAR_OUTPUTS.get(algorithm, POLICY_NODE)
    if output not in nodes:
        problems.append(f"{where}: no output {output} (simapp FROZEN_HEAD_OUTPUT_GRAPH_FORMAT_MAPPING)")
    return problems


def _counts_as_model(name: str) -> bool:
    """Whether the car's loader takes ``name`` for a model file: systems ``model_loader_node.py:418-420`` tests
    ``ext not in ".pb"`` against the string of ``:108``, so ``.pb`` and no extension (also ``.`` and ``.p``) count."""
    return os.path.splitext(name)[1] in ".pb"


def car_archive_problems(path: str | Path) -> list[str]:
    """Every check the car's upload and loader make on an archive, as one line each (module docstring)."""
    path = Path(path)
    if not path.name.endswith(".tar.gz"):  # webserver models.py:663-667
        return [f"{path.name}: not a .tar.gz (webserver models.py model_file_upload)"]
    try:  # systems model_loader_node.py:385-397: gunzip then untar; a failure ignores the archive
        with tarfile.open(path, "r:gz") as tar:
            members = {m.name.removeprefix("./"): m for m in tar.getmembers() if m.isfile()}
            top = members.get("model_metadata.json")
            metadata_bytes = tar.extractfile(top).read() if top is not None else None  # type: ignore[union-attr]
            pbs = [name for name in members if _counts_as_model(name)]
            pb = tar.extractfile(members[pbs[0]]).read() if len(pbs) == 1 else b""  # type: ignore[union-attr]
    except (tarfile.TarError, OSError, EOFError) as err:
        return [f"{path.name}: not a gzipped tar ({err}) (extract_archive)"]
    if len(pbs) != 1:  # model_loader_node.py:414-427 lists every folder; :576-585 refuse none and more than one
        return [
            f"{path.name}: {len(pbs)} model files (.pb or no extension); the loader takes exactly one (transfer_models)"
        ]
    # model_install_state.py:115-123 copies only the top folder's model_metadata.json; loading then reads it
    # (webserver models.py:524-532, read_model_metadata_file at :181-184).
    if metadata_bytes is None:
        return [f"{path.name}: no model_metadata.json at the top (model_install_state.py)"]
    try:
        metadata = json.loads(metadata_bytes)
    except ValueError as err:  # models.py:185-191
        return [f"{path.name}: model_metadata.json is not JSON ({err}) (read_model_metadata_file)"]
    return metadata_problems(metadata, "model_metadata.json") + graph_problems(pb, metadata, pbs[0])


def simapp_metadata_problems(metadata: dict[str, Any], where: str) -> list[str]:
    """What the simapp's model validation refuses in model/model_metadata.json beyond the car's checks (simapp
    ``markov/boto/s3/files/model_metadata.py:227-254``, run by ``markov/validation_worker.py:141-157``)."""
    problems = []
    if "action_space" not in metadata:  # model_metadata.py:227-228
        problems.append(f"{where}: no action_space (simapp model_metadata.py)")
    sensors = metadata.get("sensor", ["observation"])
    sensors = sensors if isinstance(sensors, list) else []
    if sum(s in SIM_CAMERAS for s in sensors) != 1:  # model_metadata.py:245-249
        problems.append(f"{where}: sensor {sensors} needs exactly one camera (simapp model_metadata.py)")
    if sum(s in SIM_LIDARS for s in sensors) > 1:  # model_metadata.py:251-254
        problems.append(f"{where}: sensor {sensors} has more than one lidar (simapp model_metadata.py)")
    return problems


def _read(path: Path, parse: Any) -> Any:
    """``parse`` of ``path``'s text, or None where it is absent or does not parse (its own check names it)."""
    try:
        return parse(path.read_text())
    except (OSError, ValueError, yaml.YAMLError):
        return None


def _metadata(folder: Path, rel: str, problems: list[str]) -> dict[str, Any] | None:
    """The JSON object in ``folder/rel``; None where it is absent (checked elsewhere) or, noted in ``problems``, not
    one (DoA ImportHelper.ts:43 and simapp model_metadata.py:224 parse it)."""
    if not (folder / rel).is_file():
        return None
    data = _read(folder / rel, json.loads)
    if not isinstance(data, dict):
        problems.append(f"{rel} is not a JSON object (JSON.parse / json.load)")
        return None
    return data


def sim_folder_problems(folder: str | Path) -> list[str]:
    """Every check DRfC's upload and DeepRacer on AWS's import make on a folder, as one line each."""
    folder = Path(folder)
    files = [p for p in folder.rglob("*") if p.is_file()]
    names = {p.name for p in files}
    # DoA ImportModel.tsx:54-56: each REQUIRED_FILES_FOR_IMPORT name anywhere in the folder (constants.ts:6-11).
    problems = [f"missing {name} (REQUIRED_FILES_FOR_IMPORT)" for name in SIM_REQUIRED if name not in names]
    if sum(p.stat().st_size for p in files) > SIM_MAX_BYTES:  # ImportModel.tsx:49-52 (constants.ts:4)
        problems.append("over 1 GB (MAX_FOLDER_SIZE)")
    # DoA ImportHelper.ts:38,54,69,139 read these keys (each throws when absent); upload-model.sh:223-227 puts them
    # there; the simapp validation reads model/model_metadata.json (simapp markov/boto/s3/constants.py:50,
    # validation_worker.py:141-144), which upload-model.sh:198 copies.
    for rel in ("model_metadata.json", "reward_function.py", "training_params.yaml", "ip/hyperparameters.json"):
        if not (folder / rel).is_file():
            problems.append(f"missing {rel} (ImportHelper.ts / upload-model.sh)")
    if not (folder / "model" / "model_metadata.json").is_file():
        problems.append("missing model/model_metadata.json (simapp MODEL_METADATA_S3_POSTFIX / upload-model.sh)")
    # DoA docs/import/README.md:16; simapp markov/boto/s3/constants.py:295-296 and tensorflow_model.py:126.
    state = folder / "model" / ".coach_checkpoint"
    if not state.is_file():
        return [*problems, "missing model/.coach_checkpoint (README.md)"]
    name = state.read_text().strip()
    n = name.split("_Step")[0]
    # simapp multi_agent_graph_manager.py:642 names checkpoints "{}_Step-{}.ckpt"; rl_coach checkpoint.py:254 needs
    # the leading number and ".ckpt"; upload-model.sh:179 takes <n> as the part before the first "_".
    if not (n.isdigit() and name.endswith(".ckpt")):
        problems.append(f"model/.coach_checkpoint names {name!r}, not <n>_Step-<steps>.ckpt (save_checkpoint)")
    for ext in (".index", ".data-00000-of-00001", ".meta"):  # README.md:17; tensorflow_model.py:168-178
        if not (folder / "model" / (name + ext)).is_file():
            problems.append(f"missing model/{name}{ext} (README.md: ckpt index, data, meta)")
    if not (folder / "model" / f"model_{n}.pb").is_file():  # upload-model.sh:192-193
        problems.append(f"missing model/model_{n}.pb (upload-model.sh)")
    # upload-model.sh:178-180 and :221 write deepracer_checkpoints.json with best and last both the checkpoint.
    checkpoints = _read(folder / "model" / "deepracer_checkpoints.json", json.loads)
    named = [(checkpoints or {}).get(k) for k in ("best_checkpoint", "last_checkpoint")]
    if not all(isinstance(c, dict) and c.get("name") == name for c in named):
        problems.append("model/deepracer_checkpoints.json does not name the checkpoint (upload-model.sh)")
    metadata = _metadata(folder, "model_metadata.json", problems)
    params = _read(folder / "training_params.yaml", yaml.safe_load) or {}
    if not (isinstance(params, dict) and params.get("WORLD_NAME")):  # DoA ImportHelper.ts:238-240 getTrackConfig
        problems.append("training_params.yaml has no WORLD_NAME (ImportHelper.ts getTrackConfig)")
    # SAC acts only in a continuous space: DoA docs/import/README.md:72-73; simapp
    # markov/multi_agent_coach/agents/sac_agent.py:328-329.
    if metadata and metadata.get("training_algorithm") == "sac" and metadata.get("action_space_type") != "continuous":
        problems.append("SAC needs a continuous action space (README.md: Algorithm mismatch)")
    model_metadata = _metadata(folder, "model/model_metadata.json", problems)
    if model_metadata is not None:
        problems += simapp_metadata_problems(model_metadata, "model/model_metadata.json")
    if metadata is not None:
        problems += metadata_problems(metadata, "model_metadata.json")
    return problems
