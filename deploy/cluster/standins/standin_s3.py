#!/usr/bin/env python3
"""Stand-in for MinIO (and its `mc` client) in the docker tests, where no image registry can be reached.

    standin-s3 server DIR [MinIO's other options, ignored]   serve S3 (moto) on $STANDIN_S3_ADDRESS
    standin-s3 ready                                          exit 0 once the server answers (health check)
    standin-s3 mb BUCKET                                      create BUCKET unless it exists
    mc ready ALIAS | mc alias set ALIAS URL USER PASSWORD | mc mb [--ignore-existing] ALIAS/BUCKET
        the mc commands docker-compose.yml runs (health check, minio-init), all aimed at $STANDIN_S3_ADDRESS
        whatever URL the alias names: the test runs every service on the host's network, at a free port

moto keeps objects in memory; MinIO keeps them in its /data volume, and the compose test takes everything down
and up again expecting the run to resume. So after each request that changes something the server copies the
objects it touched to DIR/<bucket>/<percent-encoded key> (path-style requests, as racer sends), and loads DIR back
when it starts. Credentials are not checked (moto accepts any).
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
import urllib.parse
import urllib.request

ADDRESS = os.environ.get("STANDIN_S3_ADDRESS", "127.0.0.1:9000")
READY = "/tmp/standin-s3.ready"


def _url(path: str = "/") -> str:
    return f"http://{ADDRESS}{path}"


def _client():
    import boto3
    from botocore.config import Config

    return boto3.client(
        "s3",
        endpoint_url=_url(),
        region_name="us-east-1",
        aws_access_key_id=os.environ.get("MINIO_ROOT_USER", "standin"),
        aws_secret_access_key=os.environ.get("MINIO_ROOT_PASSWORD", "standin"),
        config=Config(s3={"addressing_style": "path"}, retries={"max_attempts": 1}),
    )


class Mirror:
    """The buckets' objects as files under a folder, kept in step with the server."""

    def __init__(self, root: str) -> None:
        self.root = root
        self.lock = threading.Lock()
        self.paused = False
        self.s3 = None

    def _path(self, bucket: str, key: str = "") -> str:
        folder = os.path.join(self.root, bucket)
        return os.path.join(folder, urllib.parse.quote(key, safe="")) if key else folder

    def changed(self, method: str, path: str, query: str) -> None:
        """After a request that may have changed something: copy what it touched."""
        if self.paused:
            return
        bucket, _, key = path.lstrip("/").partition("/")
        if not bucket or bucket == "moto-api":
            return
        with self.lock:
            self.s3 = self.s3 or _client()
            if key:
                self._sync_key(bucket, key)
            else:
                self._sync_bucket(bucket)  # CreateBucket, DeleteBucket, DeleteObjects (POST ?delete)

    def _sync_key(self, bucket: str, key: str) -> None:
        from botocore.exceptions import ClientError

        try:
            body = self.s3.get_object(Bucket=bucket, Key=key)["Body"].read()
        except ClientError as exc:
            if exc.response.get("Error", {}).get("Code") in ("NoSuchKey", "404", "NoSuchBucket"):
                if os.path.exists(self._path(bucket, key)):
                    os.remove(self._path(bucket, key))
                return
            raise
        os.makedirs(self._path(bucket), exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.root, prefix=".partial-")
        with os.fdopen(fd, "wb") as f:
            f.write(body)
        os.replace(tmp, self._path(bucket, key))

    def _sync_bucket(self, bucket: str) -> None:
        from botocore.exceptions import ClientError

        try:
            keys = set()
            for page in self.s3.get_paginator("list_objects_v2").paginate(Bucket=bucket):
                keys.update(o["Key"] for o in page.get("Contents", []))
        except ClientError:  # the bucket is gone
            shutil.rmtree(self._path(bucket), ignore_errors=True)
            return
        os.makedirs(self._path(bucket), exist_ok=True)
        for name in os.listdir(self._path(bucket)):
            if urllib.parse.unquote(name) not in keys:
                os.remove(os.path.join(self._path(bucket), name))
        for key in keys - {urllib.parse.unquote(n) for n in os.listdir(self._path(bucket))}:
            self._sync_key(bucket, key)

    def restore(self) -> int:
        """Put the mirrored objects back into the (empty) server; returns how many."""
        self.paused, n = True, 0
        s3 = _client()
        for bucket in sorted(os.listdir(self.root)):
            if bucket.startswith(".") or not os.path.isdir(self._path(bucket)):
                continue
            s3.create_bucket(Bucket=bucket)
            for name in sorted(os.listdir(self._path(bucket))):
                with open(os.path.join(self._path(bucket), name), "rb") as f:
                    s3.put_object(Bucket=bucket, Key=urllib.parse.unquote(name), Body=f.read())
                n += 1
        self.paused = False
        return n


def server(data_dir: str) -> int:
    from moto.moto_server.werkzeug_app import DomainDispatcherApplication, MotoRequestHandler, create_backend_app
    from werkzeug.serving import make_server

    logging.getLogger("werkzeug").setLevel(logging.WARNING)  # not a line per request
    os.makedirs(data_dir, exist_ok=True)
    if os.path.exists(READY):  # left by this container's previous start
        os.remove(READY)
    for name in os.listdir(data_dir):
        if name.startswith(".partial-"):
            os.remove(os.path.join(data_dir, name))
    mirror = Mirror(data_dir)
    app = DomainDispatcherApplication(create_backend_app)

    def mirrored(environ, start_response):
        response = app(environ, start_response)  # moto has done the work when this returns
        if environ["REQUEST_METHOD"] in ("PUT", "POST", "DELETE"):
            path = environ.get("PATH_INFO", "").encode("latin-1").decode("utf-8")
            mirror.changed(environ["REQUEST_METHOD"], path, environ.get("QUERY_STRING", ""))
        return response

    host, port = ADDRESS.rsplit(":", 1)
    srv = make_server(host, int(port), mirrored, threaded=True, request_handler=MotoRequestHandler)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    started = time.monotonic()
    n = mirror.restore()
    print(f"standin-s3: {n} objects loaded from {data_dir} in {time.monotonic() - started:.1f} s", flush=True)
    open(READY, "w").close()
    print(f"standin-s3: S3 (moto) on http://{ADDRESS}, objects mirrored in {data_dir}", flush=True)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()
    srv.shutdown()
    return 0


def ready() -> int:
    if not os.path.exists(READY):
        return 1
    try:
        urllib.request.urlopen(_url(), timeout=3)
    except OSError:
        return 1
    return 0


def make_bucket(bucket: str) -> int:
    s3 = _client()
    last: Exception | None = None
    for _ in range(60):
        try:
            existing = {b["Name"] for b in s3.list_buckets().get("Buckets", [])}
            break
        except Exception as exc:  # the server may still be starting
            last = exc
            time.sleep(1)
    else:
        print(f"standin-s3: cannot reach {_url()}: {last}", file=sys.stderr)
        return 1
    if bucket not in existing:
        s3.create_bucket(Bucket=bucket)
    print(f"standin-s3: bucket {bucket} ready", flush=True)
    return 0


def mc(argv: list[str]) -> int:
    """The few mc commands docker-compose.yml runs."""
    if len(argv) == 2 and argv[0] == "ready":
        return ready()
    if len(argv) == 6 and argv[:2] == ["alias", "set"]:
        print(f"mc (stand-in): alias {argv[2]} is S3 at http://{ADDRESS}", flush=True)
        return 0
    args = [a for a in argv[1:] if a not in ("--ignore-existing", "-p")]
    if argv[:1] == ["mb"] and len(args) == 1 and "/" in args[0]:
        return make_bucket(args[0].split("/", 1)[1])
    print(f"mc (stand-in): unsupported: mc {' '.join(argv)}", file=sys.stderr)
    return 2


def main(argv: list[str]) -> int:
    if os.path.basename(sys.argv[0]) == "mc":
        return mc(argv)
    if len(argv) >= 2 and argv[0] == "server":
        return server(argv[1])
    if argv == ["ready"]:
        return ready()
    if len(argv) == 2 and argv[0] == "mb":
        return make_bucket(argv[1])
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
