"""docker-compose.yml, its overrides and the Dockerfile, read as files: they parse and match the CLI they drive,
nothing is open by default, and the test overrides keep to what deploy/cluster/check-compose.sh and
deploy/cluster/check-swarm.sh rely on. tests/test_docker.py runs them for real where a Docker daemon answers."""

import re
import shutil
import subprocess
from pathlib import Path

import pytest
import typer
import yaml

from racer.cli import app

ROOT = Path(__file__).resolve().parents[1]
SECRETS = ("REDIS_PASSWORD", "MINIO_ROOT_USER", "MINIO_ROOT_PASSWORD")
ROLES = ("trainer", "worker", "evaluator")


def load(name: str) -> dict:
    return yaml.safe_load((ROOT / name).read_text())


def compose() -> dict:
    return load("docker-compose.yml")


def envvars(command: str) -> set[str]:
    group = typer.main.get_command(app)
    cmd = group.commands[command]
    return {p.envvar for p in cmd.params if getattr(p, "envvar", None)}


def interpolations(text: str) -> list[tuple[str, str, str]]:
    """Every ${NAME<op>arg} in a compose file: (name, op, arg)."""
    return re.findall(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(:?[-?]|)([^}]*)\}", text)


def test_services_and_healthchecks():
    services = compose()["services"]
    assert {"redis", "minio", "minio-init", "trainer", "worker", "evaluator"} <= set(services)
    for name in ("redis", "minio", "trainer"):
        assert "healthcheck" in services[name], name
    assert services["trainer"]["depends_on"]["redis"]["condition"] == "service_healthy"
    assert services["trainer"]["depends_on"]["minio-init"]["condition"] == "service_completed_successfully"
    assert "mc mb" in services["minio-init"]["entrypoint"][-1]


def test_worker_count_comes_from_workers_variable():
    assert compose()["services"]["worker"]["deploy"]["replicas"] == "${WORKERS:-2}"


def test_role_commands_exist_and_take_every_variable_compose_sets():
    services = compose()["services"]
    for role in ROLES:
        svc = services[role]
        assert svc["command"] == [role]
        names = set(svc["environment"]) - {"AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_DEFAULT_REGION"}
        assert names <= envvars(role), names - envvars(role)
    assert {"RACER_RUN_ID", "RACER_REDIS_URL", "RACER_STORE", "AWS_ENDPOINT_URL"} <= envvars("worker")


def option_defaults(command: str) -> dict[str, object]:
    """The default of each option of ``racer COMMAND`` that reads an environment variable, by variable."""
    cmd = typer.main.get_command(app).commands[command]
    return {p.envvar: p.default for p in cmd.params if getattr(p, "envvar", None)}


COMPOSE_FILES = ["docker-compose.yml", *(str(p.relative_to(ROOT)) for p in sorted(ROOT.glob("deploy/**/*.yml")))]


@pytest.mark.parametrize("name", COMPOSE_FILES)
def test_a_compose_default_is_the_role_s_own_default(name):
    """A role's defaults live in one place (``common/defaults.py``, through its command's options): a compose or swarm
    file that passes a variable on with a fallback (``${RACER_EVAL_NICE:-5}``) must fall back to the same value,
    so that a run under compose is the run ``racer train`` makes."""
    checked = 0
    for service in (load(name).get("services") or {}).values():
        role = (service.get("command") or [None])[0]
        if role not in ROLES or not isinstance(service.get("environment"), dict):
            continue
        defaults = option_defaults(role)
        for var, value in service["environment"].items():
            found = re.fullmatch(r"\$\{(\w+):-([^}]*)\}", str(value))
            if found and found.group(1) == var and defaults.get(var) is not None:
                assert str(defaults[var]) == found.group(2), (name, role, var, defaults[var], found.group(2))
                checked += 1
    if name == "docker-compose.yml":
        assert checked >= 4  # the track, the trainer's threads, the evaluator's starts and nice at least


def test_store_and_redis_point_at_the_compose_services():
    env = compose()["services"]["worker"]["environment"]
    url = env["RACER_REDIS_URL"]
    assert url.startswith("redis://:${REDIS_PASSWORD:?") and url.endswith("}@redis:6379/0")
    assert env["RACER_STORE"].startswith("s3://") and env["AWS_ENDPOINT_URL"] == "http://minio:9000"


def test_dockerfile_pins_cpu_torch_and_uses_the_racer_entrypoint():
    text = (ROOT / "Dockerfile").read_text()
    assert "torch==2.13.0" in text and "download.pytorch.org/whl/cpu" in text
    assert 'ENTRYPOINT ["racer"]' in text


def test_the_trainer_healthcheck_is_racer_status_with_its_options_from_the_environment():
    trainer = compose()["services"]["trainer"]
    assert trainer["healthcheck"]["test"] == ["CMD", "racer", "status", "--quiet"]
    group = typer.main.get_command(app)
    # Without them racer status looks for a racer train on its machine (runs/<id>/redis.json): compose has none.
    needed = {p.envvar for p in group.commands["status"].params if p.name in ("redis_url", "run_id")}
    assert needed == {"RACER_REDIS_URL", "RACER_RUN_ID"} and needed <= set(trainer["environment"])


# --- images ----------------------------------------------------------------------------------------------------------


def test_the_dockerfile_takes_the_base_image_and_the_torch_source_as_build_arguments():
    text = (ROOT / "Dockerfile").read_text()
    assert "ARG BASE_IMAGE=python:3.11-slim\nFROM ${BASE_IMAGE}\n" in text
    assert "ARG TORCH_SPEC=torch==2.13.0" in text
    assert "ARG TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu" in text
    assert '"${TORCH_SPEC}" --index-url "${TORCH_INDEX_URL}"' in text
    assert text.count("FROM ") == 1 and text.count("ENTRYPOINT") == 1  # one image for every role
    users = re.findall(r"^USER (\S+)", text, re.M)
    assert users and users[-1] not in ("root", "0")


def test_one_image_for_every_role():
    services = compose()["services"]
    assert services["trainer"]["build"] == "."
    assert {services[r]["image"] for r in ROLES} == {"${RACER_IMAGE:-racer:latest}"}


def test_the_build_context_is_only_what_the_dockerfile_copies():
    lines = [ln for ln in (ROOT / ".dockerignore").read_text().splitlines() if ln and not ln.startswith("#")]
    assert lines[0] == "*"  # everything out, then the Dockerfile's inputs back in
    allowed = {ln[1:].rstrip("/") for ln in lines if ln.startswith("!")}
    copied = set()
    for line in (ROOT / "Dockerfile").read_text().splitlines():
        if line.startswith("COPY "):
            copied.update(line.split()[1:-1])
    assert copied == allowed
    for heavy in (".venv", ".git", "runs", "tests", "docs", ".env"):
        assert heavy not in allowed
    assert "deploy/cluster/" in lines  # the cluster test harness runs from a checkout, never in the image


# --- nothing open by default ---------------------------------------------------------------------------------------


def test_no_secret_has_a_default_and_a_missing_one_names_the_env_line_to_add():
    text = (ROOT / "docker-compose.yml").read_text()
    uses = [(n, op, arg) for n, op, arg in interpolations(text) if n in SECRETS]
    assert {n for n, _, _ in uses} == set(SECRETS)
    for name, op, arg in uses:
        assert op == ":?", f"${{{name}}} must be ${{{name}:?...}}, not {op!r}"
        assert f"add the line {name}=" in arg and ".env" in arg, arg
    assert "racer-secret" not in text


def test_redis_asks_for_the_password_and_racer_gives_it():
    redis = compose()["services"]["redis"]
    command = redis["command"]
    i = command.index("--requirepass")
    assert command[i + 1].startswith("${REDIS_PASSWORD:?")
    assert redis["environment"]["REDISCLI_AUTH"].startswith("${REDIS_PASSWORD:?")  # for the health check


def test_no_port_is_published_unless_deploy_compose_publish_yml_is_added():
    services = compose()["services"]
    assert all("ports" not in s for s in services.values())
    assert '# ports: ["127.0.0.1:9001:9001"]' in (ROOT / "docker-compose.yml").read_text()  # the console, if asked
    publish = load("deploy/compose.publish.yml")["services"]
    assert set(publish) == {"redis", "minio"}
    for name, port in (("redis", 6379), ("minio", 9000)):
        (spec,) = publish[name]["ports"]
        assert spec.startswith("${RACER_PUBLISH_ADDR:?") and spec.endswith(f"}}:{port}:{port}")


def test_env_example_lists_every_required_variable_empty():
    example = (ROOT / ".env.example").read_text()
    for name in SECRETS:
        assert re.search(rf"^{name}=$", example, re.M), name
    required = {n for n, op, _ in interpolations((ROOT / "docker-compose.yml").read_text()) if op in (":?", "?")}
    assert required == set(SECRETS)


@pytest.mark.parametrize("compose_cmd", [["docker", "compose"], ["docker-compose"]], ids=["v2", "v1"])
def test_compose_up_without_the_secrets_stops_naming_the_line_to_add(compose_cmd, tmp_path):
    """Compose itself (no daemon needed for `config`), where installed."""
    if shutil.which(compose_cmd[0]) is None:
        pytest.skip(f"{compose_cmd[0]} is not installed")
    probe = subprocess.run([*compose_cmd, "version"], capture_output=True, text=True, timeout=60)
    if probe.returncode != 0:
        pytest.skip(f"{' '.join(compose_cmd)} is not installed")
    shutil.copy(ROOT / "docker-compose.yml", tmp_path)
    (tmp_path / ".env").write_text("REDIS_PASSWORD=\n")  # present but empty counts as missing
    env = {"PATH": "/usr/local/bin:/usr/bin:/bin", "HOME": str(tmp_path)}
    out = subprocess.run([*compose_cmd, "config"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode != 0
    assert "add the line REDIS_PASSWORD=" in out.stderr or "add the line MINIO_ROOT" in out.stderr, out.stderr
    (tmp_path / ".env").write_text("REDIS_PASSWORD=r3d1s\nMINIO_ROOT_USER=racer\nMINIO_ROOT_PASSWORD=m1n10-pass\n")
    out = subprocess.run([*compose_cmd, "config"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "redis://:r3d1s@redis:6379/0" in out.stdout


# --- the test overrides and Swarm ------------------------------------------------------------------------------------


def test_the_test_override_swaps_only_the_images_that_cannot_be_pulled_and_runs_on_the_host_network():
    base, test = compose()["services"], load("deploy/cluster/compose.test.yml")["services"]
    assert set(test) == set(base)
    assert all(svc["network_mode"] == "host" for svc in test.values())
    assert test["redis"]["image"].startswith("racer-standin-redis:")
    assert test["minio"]["image"].startswith("racer-standin-s3:")
    assert test["minio-init"]["image"] == test["minio"]["image"]
    for name, svc in test.items():
        assert "image" not in svc or name in ("redis", "minio", "minio-init"), name
        # docker stack deploy appends list values (a health check's test, an entrypoint) to the base file's:
        # the stand-ins run the base file's commands and health checks as written.
        assert "command" not in svc and "entrypoint" not in svc, name
        assert set(svc.get("healthcheck", {})) <= {"interval"}, name
    for role in ROLES:
        env = test[role]["environment"]
        assert set(env) - {"RACER_REDIS_URL", "AWS_ENDPOINT_URL"} <= envvars(role)
        assert "127.0.0.1" in env["RACER_REDIS_URL"] and "127.0.0.1" in env["AWS_ENDPOINT_URL"]
    assert test["trainer"]["build"]["args"]["BASE_IMAGE"].startswith("racer-standin-python:")
    hp = yaml.safe_load((ROOT / "deploy/cluster/compose.test.hyperparameters.json").read_text())
    assert hp["batch_size"] <= 64 and hp["num_episodes_between_training"] <= 4


def test_swarm_override_puts_every_service_on_the_host_network():
    swarm = load("deploy/cluster/swarm.test.yml")
    assert swarm["networks"]["hostnet"] == {"external": True, "name": "host"}
    assert set(swarm["services"]) == set(compose()["services"])
    assert all(svc == {"networks": ["hostnet"]} for svc in swarm["services"].values())


def test_check_swarm_turns_each_depends_on_into_the_short_form_and_changes_nothing_else():
    """docker stack deploy rejects compose's `depends_on: {svc: {condition: ...}}`; check-swarm.sh rewrites each
    such line with sed. The file must keep one condition per line for that, and the result must load as the same
    file with list-form depends_on."""
    script = (ROOT / "deploy/cluster/check-swarm.sh").read_text()
    (expr,) = re.findall(r"sed -E '(s/.*/)' \"\$ROOT/docker-compose.yml\"", script)
    _, pattern, replacement, _ = expr.split("/")
    text = (ROOT / "docker-compose.yml").read_text()
    stack = yaml.safe_load(re.sub(pattern, replacement.replace("\\1", r"\1").replace("\\2", r"\2"), text, flags=re.M))
    original = compose()
    for name, svc in original["services"].items():
        if "depends_on" in svc:
            assert stack["services"][name]["depends_on"] == list(svc["depends_on"]), name
            svc = {**svc, "depends_on": list(svc["depends_on"])}
        assert stack["services"][name] == svc, name
    assert all(isinstance(s.get("depends_on", []), list) for s in stack["services"].values())


def test_no_interpolation_message_contains_a_dash():
    """docker stack deploy reads `${VAR:?message}` with a '-' in the message as `${VAR-default}`."""
    for name in (
        "docker-compose.yml",
        "deploy/cluster/compose.test.yml",
        "deploy/compose.publish.yml",
        "deploy/compose.gpu.yml",
    ):
        for var, op, arg in interpolations((ROOT / name).read_text()):
            if "?" in op:
                assert "-" not in arg, (name, var, arg)


def test_restart_policies_for_compose_and_swarm():
    services = compose()["services"]
    for role in ROLES:
        assert services[role]["restart"] == "on-failure"
        assert services[role]["deploy"]["restart_policy"] == {"condition": "on-failure"}
    assert services["minio-init"]["deploy"]["restart_policy"] == {"condition": "on-failure"}  # a one-shot job


# --- the trainer on a GPU --------------------------------------------------------------------------------------------


def test_the_gpu_override_reserves_one_nvidia_gpu_for_the_trainer_and_asks_it_to_use_cuda():
    from trainer.device import check_device

    base, gpu = compose()["services"], load("deploy/compose.gpu.yml")["services"]
    assert set(gpu) == set(ROLES) and set(gpu) <= set(base)
    trainer = gpu["trainer"]
    assert trainer["deploy"]["resources"]["reservations"]["devices"] == [
        {"driver": "nvidia", "count": 1, "capabilities": ["gpu"]}
    ]
    assert "RACER_DEVICE" in envvars("trainer") and check_device(trainer["environment"]["RACER_DEVICE"]) == "cuda"
    for role in ("worker", "evaluator"):  # no reservation: they act on the CPU, from the same image
        assert "deploy" not in gpu[role] and "environment" not in gpu[role]
    assert {svc["image"] for svc in gpu.values()} == {"${RACER_IMAGE:-racer:gpu}"}  # one image, not the CPU one's tag


def test_the_gpu_override_builds_with_a_torch_index_the_user_names():
    gpu = load("deploy/compose.gpu.yml")["services"]["trainer"]
    args = gpu["build"]["args"]
    dockerfile_args = set(re.findall(r"^ARG (\w+)", (ROOT / "Dockerfile").read_text(), re.M))
    assert set(args) <= dockerfile_args and gpu["build"]["context"] == "."
    ((name, op, message),) = interpolations(args["TORCH_INDEX_URL"])
    assert (name, op) == ("RACER_TORCH_INDEX_URL", ":?") and "add the line RACER_TORCH_INDEX_URL=" in message
    assert re.search(r"^# RACER_TORCH_INDEX_URL=$", (ROOT / ".env.example").read_text(), re.M)
