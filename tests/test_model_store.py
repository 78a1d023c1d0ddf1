"""model_store: the object-store interface on a directory and on S3 (moto's server, over real HTTP), and the run
layout on top of it."""

import json
import socket
import time
import uuid
from concurrent.futures import ThreadPoolExecutor

import boto3
import pytest
from botocore.config import Config

from model_store import (
    LocalStore,
    RunStore,
    S3Store,
    StoreError,
    StoreKeyError,
    StoreUnavailable,
    is_transient,
    list_models,
    open_store,
)

BUCKET = "racer-models"
SECRET = "testing-secret"  # conftest's fake AWS_SECRET_ACCESS_KEY; it must never show up in an error message


@pytest.fixture(scope="module")
def s3_endpoint(s3_server):
    """The session's moto S3 server (tests/conftest.py) with this module's bucket."""
    boto3.client("s3", endpoint_url=s3_server).create_bucket(Bucket=BUCKET)
    return s3_server


@pytest.fixture(params=["local", "s3"])
def store(request, tmp_path):
    """Each behavioural test runs on a LocalStore in tmp_path and on an S3Store under a fresh prefix."""
    if request.param == "local":
        return LocalStore(tmp_path / "store")
    endpoint = request.getfixturevalue("s3_endpoint")
    return S3Store(BUCKET, f"t-{uuid.uuid4().hex}", endpoint)


def _free_port() -> int:
    # Bind to port 0 to get a free port, then close it: nothing listens there afterwards.
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- ObjectStore -------------------------------------------------------------------------------------------------------


def test_put_get_exists_delete_round_trip(store):
    assert not store.exists("a/b.bin")
    store.put("a/b.bin", b"\x00\x01hello")
    assert store.exists("a/b.bin")
    assert store.get("a/b.bin") == b"\x00\x01hello"
    store.put("a/b.bin", b"replaced")
    assert store.get("a/b.bin") == b"replaced"
    store.delete("a/b.bin")
    assert not store.exists("a/b.bin")
    store.delete("a/b.bin")  # deleting a missing key is a no-op on both backends


def test_get_of_a_missing_key_is_a_store_key_error_naming_it(store):
    with pytest.raises(StoreKeyError) as info:
        store.get("nope/missing.json")
    assert isinstance(info.value, KeyError) and isinstance(info.value, StoreError)
    assert "nope/missing.json" in str(info.value)
    assert not str(info.value).startswith("'")  # plain message, not KeyError's quoted repr


def test_list_with_a_prefix_gives_sorted_keys_and_sizes(store):
    for key, data in [("runs/b/x", b"123"), ("runs/a/y", b"1"), ("runs/a.txt", b"12"), ("other/z", b"")]:
        store.put(key, data)
    infos = list(store.list("runs/"))
    assert [(i.key, i.size) for i in infos] == [("runs/a.txt", 2), ("runs/a/y", 1), ("runs/b/x", 3)]
    assert all(abs(i.modified - time.time()) < 600 for i in infos)
    assert [i.key for i in store.list("runs/a")] == ["runs/a.txt", "runs/a/y"]  # a string prefix, as in S3
    assert [i.key for i in store.list()] == ["other/z", "runs/a.txt", "runs/a/y", "runs/b/x"]
    assert list(store.list("nothing/")) == []


def test_keys_that_escape_the_store_are_rejected(store, tmp_path):
    for bad in ["../x", "a/../../x", "/etc/passwd", "", "a//b"]:
        with pytest.raises(StoreError):
            store.put(bad, b"x")
    assert not (tmp_path / "x").exists()


def test_local_store_creates_its_root_on_first_write_and_leaves_no_temp_files(tmp_path):
    store = LocalStore(tmp_path / "deep" / "root")
    assert list(store.list()) == []
    store.put("k/v", b"data")
    assert [p.name for p in (tmp_path / "deep" / "root" / "k").iterdir()] == ["v"]


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_s3_list_pages_past_1000_keys(s3_endpoint):
    store = S3Store(BUCKET, f"page-{uuid.uuid4().hex}", s3_endpoint)
    keys = [f"many/{i:05d}" for i in range(1005)]
    with ThreadPoolExecutor(max_workers=16) as pool:
        list(pool.map(lambda k: store.put(k, b"x"), keys))
    calls = []
    store.client.meta.events.register("after-call.s3.ListObjectsV2", lambda **kw: calls.append(1))
    listed = store.list("many/")
    assert not calls  # lazy: nothing requested until iterated
    assert [i.key for i in listed] == keys
    assert len(calls) == 2  # S3 pages at 1000 keys


# -- open_store --------------------------------------------------------------------------------------------------------


def test_open_store_s3_uri_gives_bucket_and_prefix(s3_endpoint):
    store = open_store("s3://my-bucket/pre/fix/", endpoint=s3_endpoint)
    assert isinstance(store, S3Store)
    assert (store.bucket, store.prefix, store.uri) == ("my-bucket", "pre/fix", "s3://my-bucket/pre/fix")
    assert open_store("s3://just-bucket").prefix == ""


def test_open_store_takes_the_endpoint_from_aws_endpoint_url(s3_endpoint, monkeypatch):
    monkeypatch.setenv("AWS_ENDPOINT_URL", s3_endpoint)
    store = open_store(f"s3://{BUCKET}/env-{uuid.uuid4().hex}")
    store.put("k", b"v")
    assert store.get("k") == b"v"


def test_open_store_path_gives_local_store(tmp_path):
    store = open_store(str(tmp_path / "runs"))
    assert isinstance(store, LocalStore) and store.root == tmp_path / "runs"
    assert isinstance(open_store(f"file://{tmp_path}"), LocalStore)


@pytest.mark.parametrize("uri", ["s3://", "s3:///prefix", "gs://bucket/x", "", "s3://bad bucket/x"])
def test_open_store_rejects_bad_uris_naming_them(uri):
    with pytest.raises(StoreError) as info:
        open_store(uri)
    assert repr(uri) in str(info.value) or uri == ""


# -- S3 errors ---------------------------------------------------------------------------------------------------------


def test_nonexistent_bucket_is_a_store_error_naming_it(s3_endpoint):
    store = S3Store("no-such-bucket-42", "p", s3_endpoint)
    for call in (lambda: store.get("k"), lambda: store.put("k", b"v"), lambda: list(store.list("x/"))):
        with pytest.raises(StoreError) as info:
            call()
        assert not isinstance(info.value, StoreKeyError)
        assert "bucket 'no-such-bucket-42' does not exist" in str(info.value)
        assert SECRET not in str(info.value)


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_unreachable_endpoint_fails_fast_with_cannot_reach(s3_endpoint):
    endpoint = f"http://user:hunter2@127.0.0.1:{_free_port()}"
    store = S3Store(BUCKET, "", endpoint)  # the default config: 5 attempts, but a refused connect is instant
    start = time.monotonic()
    for call in (lambda: store.get("k"), lambda: list(store.list()), lambda: store.exists("k")):
        with pytest.raises(StoreError, match="cannot reach S3 endpoint http://127.0.0.1:") as info:
            call()
        message = str(info.value)
        assert "\n" not in message and SECRET not in message and "hunter2" not in message
    assert time.monotonic() - start < 20


def test_s3_client_config_defaults_and_overrides(s3_endpoint):
    cfg = S3Store(BUCKET, "", s3_endpoint).client.meta.config
    # botocore reads max_attempts=5 as five retries after the first try: six attempts in all.
    assert cfg.retries == {"mode": "standard", "total_max_attempts": 6}
    assert (cfg.connect_timeout, cfg.read_timeout) == (5, 30)
    cfg = S3Store(BUCKET, "", s3_endpoint, config=Config(read_timeout=7)).client.meta.config
    assert (cfg.retries["total_max_attempts"], cfg.read_timeout) == (6, 7)


def test_missing_credentials_say_how_to_set_them(s3_endpoint, monkeypatch):
    for name in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_CONTAINER_CREDENTIALS_FULL_URI"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.delenv("AWS_CONTAINER_CREDENTIALS_RELATIVE_URI", raising=False)
    monkeypatch.setenv("AWS_EC2_METADATA_DISABLED", "true")  # no instance-role lookup
    store = S3Store(BUCKET, "", s3_endpoint)
    with pytest.raises(StoreError, match="no S3 credentials found"):
        store.get("k")


def test_error_messages_never_contain_the_secret(s3_endpoint):
    store = S3Store(BUCKET, "secret-check", s3_endpoint)
    messages = []
    for call in (lambda: store.get("missing"), lambda: RunStore(store).load_checkpoint("run1", "latest")):
        with pytest.raises(StoreError) as info:
            call()
        messages.append(str(info.value))
    assert messages and all(SECRET not in m and "\n" not in m for m in messages)


# -- RunStore ----------------------------------------------------------------------------------------------------------


def _save(runs: RunStore, run_id: str, versions) -> None:
    for v in versions:
        runs.save_checkpoint(run_id, v, f"weights-{v}".encode(), {"env_steps": 1000 * v, "reward": 0.5 * v})


def test_three_checkpoints_list_in_order_with_latest_on_the_last(store):
    runs = RunStore(store)
    _save(runs, "run1", [1, 2, 3])
    ckpts = runs.list_checkpoints("run1")
    assert [c["version"] for c in ckpts] == [1, 2, 3]
    assert [c["latest"] for c in ckpts] == [False, False, True]
    assert [c["best"] for c in ckpts] == [False, False, False]
    assert ckpts[1]["size_bytes"] == len(b"weights-2") and ckpts[1]["env_steps"] == 2000
    assert ckpts[0]["run_id"] == "run1" and isinstance(ckpts[0]["created"], float)


def test_save_returns_full_metadata_and_load_latest_returns_bytes_and_meta(store):
    runs = RunStore(store)
    _save(runs, "run1", [1, 2])
    meta = runs.save_checkpoint("run1", 3, b"weights-3", {"env_steps": 3000, "created": 123.0})
    assert meta == {"env_steps": 3000, "created": 123.0, "run_id": "run1", "version": 3, "size_bytes": 9}
    payload, loaded = runs.load_checkpoint("run1", "latest")
    assert payload == b"weights-3" and loaded == meta
    assert runs.pointer("run1", "latest") == meta
    assert runs.load_checkpoint("run1", 2)[0] == b"weights-2"
    assert runs.load_checkpoint("run1", "1")[0] == b"weights-1"  # a CLI's --checkpoint 1
    stored = json.loads(store.get("runs/run1/checkpoints/000000003.json"))
    assert stored == meta


def test_set_pointer_best_sets_the_flag(store):
    runs = RunStore(store)
    _save(runs, "run1", [1, 2, 3])
    assert runs.pointer("run1", "best") is None
    runs.set_pointer("run1", "best", 2)
    assert [c["best"] for c in runs.list_checkpoints("run1")] == [False, True, False]
    assert runs.load_checkpoint("run1", "best")[0] == b"weights-2"
    with pytest.raises(ValueError):
        runs.set_pointer("run1", "worst", 2)


def test_a_checkpoint_pruned_between_listing_and_reading_is_left_out(store):
    # racer models ls on a live run: the trainer prunes a checkpoint after the listing saw it.
    runs = RunStore(store)
    _save(runs, "run1", [1, 2, 3])
    listing = store.list

    def list_then_prune(prefix):
        infos = list(listing(prefix))
        store.delete("runs/run1/checkpoints/000000001.json")
        return infos

    store.list = list_then_prune
    assert [c["version"] for c in runs.list_checkpoints("run1")] == [2, 3]


def test_half_written_checkpoints_are_not_listed_and_latest_stays_on_the_last_whole_one(store):
    runs = RunStore(store)
    _save(runs, "run1", [1, 2, 3])
    store.put("runs/run1/checkpoints/000000004.pt", b"crashed before its json")
    store.put("runs/run1/checkpoints/000000005.json", json.dumps({"version": 5}).encode())
    assert [c["version"] for c in runs.list_checkpoints("run1")] == [1, 2, 3]
    assert runs.pointer("run1", "latest")["version"] == 3
    assert runs.load_checkpoint("run1", "latest")[0] == b"weights-3"
    for version in (4, 5):
        with pytest.raises(StoreKeyError, match=f"checkpoint {version}"):
            runs.set_pointer("run1", "best", version)
        with pytest.raises(StoreKeyError):
            runs.load_checkpoint("run1", version)
    runs.save_checkpoint("run1", 4, b"weights-4", {})  # a retry replaces the half-written .pt
    assert runs.load_checkpoint("run1", "latest") == (b"weights-4", runs.pointer("run1", "latest"))


def test_a_whole_checkpoint_is_never_overwritten(store):
    runs = RunStore(store)
    _save(runs, "run1", [1])
    with pytest.raises(StoreError, match="already exists"):
        runs.save_checkpoint("run1", 1, b"other", {})
    assert runs.load_checkpoint("run1", 1)[0] == b"weights-1"


def test_a_retried_save_with_the_same_metadata_finishes_it_and_newest_whole_sees_past_the_pointer(store):
    runs = RunStore(store)
    _save(runs, "run1", [1])
    meta = {"env_steps": 7, "created": 1234.5}
    runs.save_checkpoint("run1", 2, b"weights-2", meta)
    runs.set_pointer("run1", "latest", 1)  # as if the writer died after the .json, before the pointer
    store.put("runs/run1/checkpoints/000000003.pt", b"crashed before its json")
    assert runs.newest_whole("run1") == 2  # whole beats the pointer; the orphan .pt does not count
    assert runs.save_checkpoint("run1", 2, b"weights-2", meta)["env_steps"] == 7  # the retry completes it
    assert runs.pointer("run1", "latest")["version"] == 2
    with pytest.raises(StoreError, match="already exists"):
        runs.save_checkpoint("run1", 2, b"weights-2", {**meta, "env_steps": 8})  # different: not a retry
    assert runs.newest_whole("empty-run") is None


def test_an_unreachable_endpoint_is_transient_and_a_missing_key_or_bucket_is_not(s3_endpoint):
    down = S3Store(BUCKET, "", f"http://127.0.0.1:{_free_port()}")
    with pytest.raises(StoreUnavailable) as unreachable:
        down.get("k")
    assert is_transient(unreachable.value)
    up = S3Store(BUCKET, f"t-{uuid.uuid4().hex}", s3_endpoint)
    with pytest.raises(StoreKeyError) as missing:
        up.get("k")
    with pytest.raises(StoreError) as no_bucket:
        S3Store("no-such-bucket-xyz", "", s3_endpoint).put("k", b"x")
    assert not is_transient(missing.value) and not is_transient(no_bucket.value)


def test_unserializable_meta_writes_nothing(store):
    runs = RunStore(store)
    with pytest.raises((TypeError, ValueError)):
        runs.save_checkpoint("run1", 1, b"w", {"reward": float("nan")})
    assert list(store.list()) == []


def test_pointer_of_a_run_without_checkpoints_is_none(store):
    runs = RunStore(store)
    runs.write_file("run1", "hyperparameters.json", "{}")
    assert runs.pointer("run1", "latest") is None
    assert runs.list_checkpoints("run1") == []
    with pytest.raises(StoreKeyError, match="run 'run1' has no latest checkpoint"):
        runs.load_checkpoint("run1", "latest")


def test_load_of_a_missing_run_is_a_store_key_error(store):
    runs = RunStore(store)
    _save(runs, "run1", [1])
    for version in ("latest", "best", 1):
        with pytest.raises(StoreKeyError, match="run 'ghost' does not exist"):
            runs.load_checkpoint("ghost", version)
    with pytest.raises(StoreKeyError, match="run 'run1' has no checkpoint 7"):
        runs.load_checkpoint("run1", 7)


@pytest.mark.parametrize("run_id", ["", "../x", "a/b", "-lead", "x" * 129, "sp ace", ".."])
def test_bad_run_id_is_a_value_error_naming_it(run_id):
    runs = RunStore(LocalStore("/nonexistent-never-written"))
    with pytest.raises(ValueError, match="invalid run id"):
        runs.save_checkpoint(run_id, 1, b"w", {})
    with pytest.raises(ValueError):
        runs.write_file(run_id, "config.json", "{}")


def test_malformed_json_is_a_store_error_naming_the_key(store):
    runs = RunStore(store)
    _save(runs, "run1", [1])
    store.put("runs/run1/latest.json", b"{not json")
    with pytest.raises(StoreError, match="malformed JSON in .*runs/run1/latest.json"):
        runs.pointer("run1", "latest")


def test_run_files_round_trip(store):
    runs = RunStore(store)
    runs.write_file("run1", "reward_function.py", "def reward_function(params):\n    return 1.0\n")
    runs.write_file("run1", "model_metadata.json", b'{"action_space": []}')
    assert runs.read_file("run1", "reward_function.py").startswith(b"def reward_function")
    assert json.loads(runs.read_file("run1", "model_metadata.json")) == {"action_space": []}
    with pytest.raises(StoreKeyError, match="run 'run1' has no file 'config.json'"):
        runs.read_file("run1", "config.json")
    with pytest.raises(ValueError):
        runs.write_file("run1", "latest.json", "{}")  # would clobber a pointer


def test_run_config_round_trip_and_a_bad_one_is_one_line_naming_run_file_key_and_value(store):
    from common.config import EnvConfig, RunConfig
    from common.defaults import STRAIGHT_TRACK

    runs = RunStore(store)
    with pytest.raises(StoreKeyError, match="run 'r1' does not exist"):
        runs.read_config("r1")
    run = RunConfig(run_id="r1", env=EnvConfig(track=STRAIGHT_TRACK), seed=7)
    runs.write_config(run)
    assert runs.read_config("r1") == run
    assert json.loads(runs.read_file("r1", "config.json"))["seed"] == 7  # the file every process reads
    bad = json.loads(runs.read_file("r1", "config.json"))
    bad["env"]["track"] = 5
    runs.write_file("r1", "config.json", json.dumps(bad))
    with pytest.raises(StoreError) as err:
        runs.read_config("r1")
    assert str(err.value) == "run r1: config.json: env.track: Input should be a valid string (got 5)"
    runs.write_file("r1", "config.json", "{not json")
    with pytest.raises(StoreError, match=r"^run r1: config.json: \(top level\): Invalid JSON") as err:
        runs.read_config("r1")
    assert "\n" not in str(err.value)


def test_metrics_and_evaluations_are_read_in_order_skipping_malformed_ones(tmp_path, caplog):
    runs = RunStore(LocalStore(tmp_path))
    runs.write_file("r", "reward_function.py", "")
    with pytest.raises(StoreKeyError, match="run 'r' has no file 'metrics.jsonl'"):
        runs.read_metrics("r")
    assert runs.read_metrics("r", missing_ok=True) == []
    assert runs.read_metrics("nope", missing_ok=True) == []
    runs.write_file("r", "metrics.jsonl", '{"iteration": 1}\n\n[1]\n{not json\n{"iteration": 2}\n')
    assert runs.read_metrics("r") == [{"iteration": 1}, {"iteration": 2}]
    assert "skipping malformed line 3 of metrics.jsonl" in caplog.text
    assert "malformed line 4" in caplog.text
    for version, score in ((8, 2.0), (4, 1.0)):
        runs.write_file("r", f"evaluations/{version:09d}.json", json.dumps({"score": score, "version": 99}))
    runs.write_file("r", "evaluations/000000009.json", "[]")
    assert runs.evaluation_versions("r") == [4, 8, 9]
    assert runs.read_evaluation("r", 8) == {"score": 2.0, "version": 99}
    with pytest.raises(StoreError, match="malformed evaluation .*000000009.json"):
        runs.read_evaluation("r", 9)
    with pytest.raises(StoreKeyError, match="no file 'evaluations/000000005.json'"):
        runs.read_evaluation("r", 5)
    # The file name is the truth for the version; the malformed one is skipped with a warning.
    assert runs.read_evaluations("r") == [{"score": 1.0, "version": 4}, {"score": 2.0, "version": 8}]
    assert "skipping evaluation 9" in caplog.text


def test_list_runs_and_list_models_across_two_runs(store):
    runs = RunStore(store)
    _save(runs, "run-a", [1, 2])
    _save(runs, "run-b", [1])
    runs.set_pointer("run-a", "best", 1)
    runs.save_checkpoint("run-b", 2, b"w", {})  # no env_steps recorded
    assert runs.list_runs() == ["run-a", "run-b"]
    models = list_models(store)
    assert [(m["run_id"], m["version"]) for m in models] == [("run-a", 1), ("run-a", 2), ("run-b", 1), ("run-b", 2)]
    required = {"run_id", "version", "env_steps", "created", "size_bytes", "latest", "best"}
    assert all(required <= m.keys() for m in models)
    assert [(m["latest"], m["best"]) for m in models] == [(False, True), (True, False), (False, False), (True, False)]
    assert [m["env_steps"] for m in models] == [1000, 2000, 1000, None]
    assert [m["version"] for m in list_models(store, "run-b")] == [1, 2]
    assert list_models(store, "no-such-run") == []
    json.dumps(models)  # the CLI writes this as --json


def test_optimizer_states_are_kept_apart_and_only_where_asked(store):
    """The optimizer state sits beside the weights, is not a checkpoint of its own (listings ignore it), and goes
    with its checkpoint when that is pruned; keep_optimizer_states drops all but the kept versions'."""
    runs = RunStore(store)
    for v in range(1, 7):
        runs.save_checkpoint("run1", v, f"weights-{v}".encode(), {"env_steps": v}, optimizer=f"adam-{v}".encode())
    assert [c["version"] for c in runs.list_checkpoints("run1")] == [1, 2, 3, 4, 5, 6]
    assert runs.load_checkpoint("run1", 6)[0] == b"weights-6" and runs.load_optimizer("run1", 6) == b"adam-6"
    assert runs.keep_optimizer_states("run1", {6, 2}) == [1, 3, 4, 5]
    assert [runs.load_optimizer("run1", v) for v in (1, 2, 5, 6)] == [None, b"adam-2", None, b"adam-6"]
    assert runs.prune_checkpoints("run1", keep_last=3) == [1, 2, 3]
    assert runs.load_optimizer("run1", 2) is None  # pruned with its weights
    names = sorted(info.key.rsplit("/", 1)[1] for info in store.list("runs/run1/checkpoints/"))
    expected = [f"00000000{v}.{ext}" for v in (4, 5, 6) for ext in ("json", "pt")] + ["000000006.optimizer.pt"]
    assert names == sorted(expected)


def test_acting_copies_sit_beside_their_checkpoints_and_go_with_them(store):
    """The acting copy (what workers load) is written before the .json makes the checkpoint whole, is no checkpoint
    of its own, is None for a checkpoint saved without one (a run from before acting copies), and is pruned with its
    checkpoint."""
    runs = RunStore(store)
    runs.save_checkpoint("run1", 1, b"weights-1", {"env_steps": 1})  # an older trainer's: no acting copy
    for v in range(2, 5):
        runs.save_checkpoint("run1", v, f"weights-{v}".encode(), {"env_steps": v}, acting=f"half-{v}".encode())
    assert [c["version"] for c in runs.list_checkpoints("run1")] == [1, 2, 3, 4]
    assert runs.load_acting("run1", 1) is None and runs.load_acting("run1", 3) == b"half-3"
    assert runs.load_checkpoint("run1", 3)[0] == b"weights-3"
    assert runs.prune_checkpoints("run1", keep_last=2) == [1, 2]
    assert runs.load_acting("run1", 2) is None and runs.load_acting("run1", 4) == b"half-4"
    names = sorted(info.key.rsplit("/", 1)[1] for info in store.list("runs/run1/checkpoints/"))
    assert names == sorted(f"00000000{v}.{ext}" for v in (3, 4) for ext in ("json", "pt", "acting.pt"))


def test_prune_run_keeps_the_newest_and_the_pointed_and_counts_what_it_frees(store):
    runs = RunStore(store)
    for v in range(1, 6):
        runs.save_checkpoint("run1", v, b"w" * 100, {"env_steps": v}, optimizer=b"o" * 200, acting=b"a" * 50)
    runs.set_pointer("run1", "best", 2)
    planned = runs.prune_run("run1", keep_last=1, dry_run=True)
    assert planned["checkpoints"] == [1, 3, 4] and planned["optimizer_states"] == [2]
    sizes = {info.key.rsplit("/", 1)[1]: info.size for info in store.list("runs/run1/checkpoints/")}
    metas = sum(sizes[f"00000000{v}.json"] for v in (1, 3, 4))
    assert planned["bytes"] == 3 * 350 + 200 + metas  # 1, 3 and 4 whole (acting copies too), 2's optimizer state
    assert [c["version"] for c in runs.list_checkpoints("run1")] == [1, 2, 3, 4, 5]  # a dry run deletes nothing
    assert runs.prune_run("run1", keep_last=1) == planned
    assert [c["version"] for c in runs.list_checkpoints("run1")] == [2, 5]
    assert runs.load_optimizer("run1", 2) is None and runs.load_optimizer("run1", 5) == b"o" * 200
    assert runs.load_acting("run1", 1) is None and runs.load_acting("run1", 2) == b"a" * 50
    with pytest.raises(StoreKeyError, match="run 'run2' does not exist"):
        runs.prune_run("run2", keep_last=1)
