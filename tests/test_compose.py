"""docker-compose.yml: Docker cannot run here, so check that it parses and matches the CLI it drives."""

from pathlib import Path

import typer
import yaml

from racer.cli import app

ROOT = Path(__file__).resolve().parents[1]


def compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def envvars(command: str) -> set[str]:
    group = typer.main.get_command(app)
    cmd = group.commands[command]
    return {p.envvar for p in cmd.params if getattr(p, "envvar", None)}


def test_services_and_healthchecks():
    services = compose()["services"]
    assert {"redis", "minio", "minio-init", "trainer", "worker"} <= set(services)
    for name in ("redis", "minio", "trainer"):
        assert "healthcheck" in services[name], name
    assert services["trainer"]["depends_on"]["redis"]["condition"] == "service_healthy"
    assert services["trainer"]["depends_on"]["minio-init"]["condition"] == "service_completed_successfully"
    assert "mc mb" in services["minio-init"]["entrypoint"][-1]


def test_worker_count_comes_from_workers_variable():
    assert compose()["services"]["worker"]["deploy"]["replicas"] == "${WORKERS:-2}"


def test_role_commands_exist_and_take_every_variable_compose_sets():
    services = compose()["services"]
    for role in ("trainer", "worker", "evaluator"):
        svc = services[role]
        assert svc["command"] == [role]
        names = set(svc["environment"]) - {"AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_DEFAULT_REGION"}
        assert names <= envvars(role), names - envvars(role)
    assert {"RACER_RUN_ID", "RACER_REDIS_URL", "RACER_STORE", "AWS_ENDPOINT_URL"} <= envvars("worker")


def test_store_and_redis_point_at_the_compose_services():
    env = compose()["services"]["worker"]["environment"]
    assert env["RACER_REDIS_URL"].startswith("redis://redis:")
    assert env["RACER_STORE"].startswith("s3://") and env["AWS_ENDPOINT_URL"] == "http://minio:9000"


def test_dockerfile_pins_cpu_torch_and_uses_the_racer_entrypoint():
    text = (ROOT / "Dockerfile").read_text()
    assert "torch==2.13.0" in text and "download.pytorch.org/whl/cpu" in text
    assert 'ENTRYPOINT ["racer"]' in text


def test_the_trainer_healthcheck_is_racer_status_with_its_options_from_the_environment():
    trainer = compose()["services"]["trainer"]
    assert trainer["healthcheck"]["test"] == ["CMD", "racer", "status", "--quiet"]
    group = typer.main.get_command(app)
    required = {p.envvar for p in group.commands["status"].params if p.required}
    assert required == {"RACER_REDIS_URL", "RACER_RUN_ID"} and required <= set(trainer["environment"])
