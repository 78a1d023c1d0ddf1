"""One object-store interface with two backends: a local directory and S3 (boto3).

Keys are '/'-separated relative names (``runs/abc/checkpoints/000000001.pt``). Both backends validate keys the same
way, so code that works against a laptop directory works unchanged against a bucket.
"""

from __future__ import annotations

import abc
import os
import re
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import boto3
import botocore.exceptions as bex
from botocore.config import Config

from common.errors import UserError
from common.files import write_atomically


class StoreError(UserError, RuntimeError):
    """A store operation failed; the message is one line naming the URI or key (never credentials)."""


class StoreUnavailable(StoreError):
    """The store did not answer, or failed on its side (HTTP 5xx, throttling): a later retry may succeed."""


class StoreKeyError(StoreError, KeyError):
    """The key (or run, or checkpoint) does not exist."""

    def __str__(self) -> str:
        # KeyError.__str__ would wrap the message in quotes; keep the plain one-line message.
        return str(self.args[0]) if self.args else ""


@dataclass(frozen=True)
class ObjectInfo:
    """One stored object: its key relative to the store, its size in bytes, its modification time (epoch s)."""

    key: str
    size: int
    modified: float


def check_key(key: str) -> str:
    """Return ``key`` if it is a valid relative '/'-separated key, else raise StoreError naming it."""
    if not isinstance(key, str) or not key:
        raise StoreError(f"invalid key {key!r}: empty")
    if key.startswith("/") or "\\" in key:
        raise StoreError(f"invalid key {key!r}: must be a relative '/'-separated path")
    if any(part in ("", ".", "..") for part in key.split("/")):
        raise StoreError(f"invalid key {key!r}: empty, '.' or '..' path component")
    return key


def _check_prefix(prefix: str) -> str:
    """A list prefix is a key prefix: '' or a key that may end in '/'."""
    if prefix:
        check_key(prefix[:-1] if prefix.endswith("/") else prefix)
    return prefix


class ObjectStore(abc.ABC):
    """Bytes under string keys. ``put`` is atomic from a reader's view: a reader sees the old object or the new one."""

    @property
    @abc.abstractmethod
    def uri(self) -> str:
        """Where the store lives: ``s3://bucket/prefix`` or a directory path."""

    @abc.abstractmethod
    def put(self, key: str, data: bytes) -> None:
        """Store ``data`` under ``key``, replacing any previous object atomically."""

    @abc.abstractmethod
    def get(self, key: str) -> bytes:
        """Return the object's bytes; StoreKeyError if it does not exist."""

    @abc.abstractmethod
    def exists(self, key: str) -> bool:
        """Whether an object is stored under ``key``."""

    @abc.abstractmethod
    def delete(self, key: str) -> None:
        """Remove the object; deleting a missing key is not an error (as in S3)."""

    @abc.abstractmethod
    def list(self, prefix: str = "") -> Iterator[ObjectInfo]:
        """Objects whose key starts with ``prefix`` (a string prefix, as in S3), sorted by key."""

    def key_uri(self, key: str) -> str:
        """The full URI of ``key``, for messages."""
        return f"{self.uri.rstrip('/')}/{key}"

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.uri!r})"


# ---------------------------------------------------------------------------------------------------------------------
# Local directory


_TMP_PREFIX = ".racer-tmp-"


class LocalStore(ObjectStore):
    """Objects as files under a root directory (created on first write)."""

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root).expanduser().absolute()

    @property
    def uri(self) -> str:
        """The root directory."""
        return str(self.root)

    def _path(self, key: str) -> Path:
        return self.root.joinpath(*check_key(key).split("/"))

    def put(self, key: str, data: bytes) -> None:
        """Write a temp file in the same directory, fsync it, then os.replace it over the key."""
        path = self._path(key)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_atomically(path, data, f"{_TMP_PREFIX}{uuid.uuid4().hex}")
        except OSError as exc:
            raise StoreError(f"cannot write {path}: {exc.strerror or type(exc).__name__}") from exc

    def get(self, key: str) -> bytes:
        """Read the file; StoreKeyError if missing."""
        path = self._path(key)
        try:
            return path.read_bytes()
        except (FileNotFoundError, NotADirectoryError, IsADirectoryError):
            raise StoreKeyError(f"no such key: {path}") from None
        except OSError as exc:
            raise StoreError(f"cannot read {path}: {exc.strerror or type(exc).__name__}") from exc

    def exists(self, key: str) -> bool:
        """Whether the file exists."""
        return self._path(key).is_file()

    def delete(self, key: str) -> None:
        """Remove the file if present (empty directories are left behind; they are never listed)."""
        path = self._path(key)
        try:
            path.unlink(missing_ok=True)
        except OSError as exc:
            raise StoreError(f"cannot delete {path}: {exc.strerror or type(exc).__name__}") from exc

    def list(self, prefix: str = "") -> Iterator[ObjectInfo]:
        """Walk the deepest directory the prefix names, filter by the string prefix, sort by key."""
        return self._walk(_check_prefix(prefix))  # validate now, not at the first next()

    def _walk(self, prefix: str) -> Iterator[ObjectInfo]:
        # The keys can only lie under the directory part of the prefix: "runs/ab" -> root/runs.
        base = self.root.joinpath(*[p for p in prefix.rpartition("/")[0].split("/") if p])
        infos = []
        for dirpath, _dirs, files in os.walk(base):
            rel = Path(dirpath).relative_to(self.root).as_posix()
            for name in files:
                key = name if rel == "." else f"{rel}/{name}"
                # Skip in-progress puts' temp files.
                if key.startswith(prefix) and not name.startswith(_TMP_PREFIX):
                    info = _stat(os.path.join(dirpath, name), key)
                    infos.extend([info] if info else [])
        yield from sorted(infos, key=lambda i: i.key)


def _stat(path: str, key: str) -> ObjectInfo | None:
    try:
        st = os.stat(path)
    except FileNotFoundError:  # deleted between the walk and the stat
        return None
    return ObjectInfo(key=key, size=st.st_size, modified=st.st_mtime)


# ---------------------------------------------------------------------------------------------------------------------
# S3

#: Retries with backoff on throttling and transient errors, and timeouts so a dead endpoint fails instead of hanging.
DEFAULT_S3_CONFIG = Config(retries={"max_attempts": 5, "mode": "standard"}, connect_timeout=5, read_timeout=30)

_NO_CREDENTIALS = "no S3 credentials found (set AWS_ACCESS_KEY_ID/AWS_SECRET_ACCESS_KEY or a profile)"
_CREDENTIAL_ERRORS = (bex.NoCredentialsError, bex.PartialCredentialsError, bex.CredentialRetrievalError)
_CONNECTION_ERRORS = (bex.ConnectionError, bex.HTTPClientError)
_MISSING_KEY_CODES = {"NoSuchKey", "404", "NotFound"}
_BAD_CREDENTIAL_CODES = {"InvalidAccessKeyId", "SignatureDoesNotMatch", "ExpiredToken", "InvalidToken"}


def _redact_url(url: str | None) -> str:
    """Drop any user:password@ from an endpoint URL before it goes into a message."""
    if not url:
        return "(default)"
    parts = urlsplit(url)
    if parts.username or parts.password:
        netloc = parts.hostname or ""
        if parts.port:
            netloc += f":{parts.port}"
        parts = parts._replace(netloc=netloc)
    return urlunsplit(parts)


class S3Store(ObjectStore):
    """Objects in an S3 bucket under a key prefix.

    Credentials come from boto3's usual chain (environment, profile, instance role); they are never arguments and
    never appear in messages. The endpoint is ``endpoint``, else ``AWS_ENDPOINT_URL``, else AWS.
    ``config`` is merged over :data:`DEFAULT_S3_CONFIG`.
    """

    def __init__(self, bucket: str, prefix: str = "", endpoint: str | None = None, *, config: Config | None = None):
        if not bucket:
            raise StoreError("S3 bucket name is empty")
        self.bucket = bucket
        self.prefix = prefix.strip("/")
        self.endpoint = endpoint or os.environ.get("AWS_ENDPOINT_URL") or None
        cfg = DEFAULT_S3_CONFIG if config is None else DEFAULT_S3_CONFIG.merge(config)
        if self.endpoint:
            # MinIO / moto / compose hostnames have no per-bucket DNS; path-style addressing works everywhere.
            cfg = cfg.merge(Config(s3={"addressing_style": "path"}))
        # A private session: boto3's default session is not thread-safe to create clients from.
        self._client = boto3.session.Session().client("s3", endpoint_url=self.endpoint, config=cfg)

    @property
    def client(self):  # boto3 clients have no importable static type
        """The underlying boto3 S3 client (thread-safe), for callers that need more than this interface."""
        return self._client

    @property
    def uri(self) -> str:
        """``s3://bucket/prefix``."""
        return f"s3://{self.bucket}/{self.prefix}" if self.prefix else f"s3://{self.bucket}"

    def _full(self, key: str) -> str:
        return f"{self.prefix}/{key}" if self.prefix else key

    @contextmanager
    def _errors(self, key: str) -> Iterator[None]:
        """Turn botocore exceptions into one-line StoreErrors naming s3://bucket/key."""
        where = f"s3://{self.bucket}/{self._full(key)}"
        try:
            yield
        except bex.ClientError as exc:
            raise self._client_error(exc, where) from exc
        except _CREDENTIAL_ERRORS as exc:
            raise StoreError(f"{_NO_CREDENTIALS} for {where}") from exc
        except _CONNECTION_ERRORS as exc:
            url = _redact_url(self._client.meta.endpoint_url)
            raise StoreUnavailable(f"cannot reach S3 endpoint {url} ({type(exc).__name__}) for {where}") from exc
        except bex.ParamValidationError as exc:
            raise StoreError(f"invalid S3 bucket or key: {where}") from exc
        except bex.BotoCoreError as exc:
            # Only the class name: botocore messages are not guaranteed to be free of request details.
            raise StoreUnavailable(f"S3 error {type(exc).__name__} on {where}") from exc

    def _client_error(self, exc: bex.ClientError, where: str) -> StoreError:
        err = exc.response.get("Error", {})
        code = str(err.get("Code", ""))
        status = exc.response.get("ResponseMetadata", {}).get("HTTPStatusCode")
        if code == "NoSuchBucket":
            return StoreError(f"bucket {self.bucket!r} does not exist ({where})")
        if code in _MISSING_KEY_CODES:
            return StoreKeyError(f"no such key: {where}")
        if code in _BAD_CREDENTIAL_CODES:
            return StoreError(f"S3 rejected the credentials ({code}) for {where}")
        if code in ("AccessDenied", "403", "AllAccessDisabled"):
            return StoreError(f"access denied to {where}")
        if (isinstance(status, int) and status >= 500) or code in ("SlowDown", "Throttling", "RequestTimeout"):
            return StoreUnavailable(f"S3 error {code or '?'} (HTTP {status}) on {where}")
        return StoreError(f"S3 error {code or '?'} (HTTP {status}) on {where}")

    def put(self, key: str, data: bytes) -> None:
        """put_object (atomic in S3: readers never see a partial object)."""
        full = self._full(check_key(key))
        with self._errors(key):
            self._client.put_object(Bucket=self.bucket, Key=full, Body=bytes(data))

    def get(self, key: str) -> bytes:
        """get_object; StoreKeyError if missing."""
        full = self._full(check_key(key))
        with self._errors(key):
            return self._client.get_object(Bucket=self.bucket, Key=full)["Body"].read()

    def exists(self, key: str) -> bool:
        """head_object. A missing bucket also answers 404 to HEAD, so it reads as False here."""
        full = self._full(check_key(key))
        try:
            with self._errors(key):
                self._client.head_object(Bucket=self.bucket, Key=full)
        except StoreKeyError:
            return False
        return True

    def delete(self, key: str) -> None:
        """delete_object (a no-op for a missing key)."""
        full = self._full(check_key(key))
        with self._errors(key):
            self._client.delete_object(Bucket=self.bucket, Key=full)

    def list(self, prefix: str = "") -> Iterator[ObjectInfo]:
        """list_objects_v2 through the paginator, one page (up to 1000 keys) at a time; S3 returns them sorted."""
        return self._pages(_check_prefix(prefix))  # validate now, not at the first next()

    def _pages(self, prefix: str) -> Iterator[ObjectInfo]:
        # With a store prefix, list("") must not match "pre/fixother/...": always end the store prefix with '/'.
        full_prefix = self._full(prefix) if prefix else (f"{self.prefix}/" if self.prefix else "")
        strip = len(f"{self.prefix}/") if self.prefix else 0
        pages = self._client.get_paginator("list_objects_v2").paginate(Bucket=self.bucket, Prefix=full_prefix)
        with self._errors(prefix):
            for page in pages:
                for obj in page.get("Contents", []):
                    yield ObjectInfo(key=obj["Key"][strip:], size=obj["Size"], modified=obj["LastModified"].timestamp())


# ---------------------------------------------------------------------------------------------------------------------

_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*)://")
_BUCKET = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


def local_store(uri: str) -> LocalStore | None:
    """The LocalStore of a directory path or ``file://`` URI, or None for a URI of another scheme (``s3://``); it
    opens nothing, so that a command can ask whether a local store exists before it reads one."""
    if not uri or not uri.strip():
        raise StoreError("empty store URI")
    m = _SCHEME.match(uri)
    if m is None:
        return LocalStore(uri)
    if m.group(1).lower() != "file":
        return None
    if not uri[m.end() :]:
        raise StoreError(f"bad store URI {uri!r}: no path")
    return LocalStore(uri[m.end() :])


def open_store(uri: str, endpoint: str | None = None) -> ObjectStore:
    """Open ``s3://bucket/optional/prefix`` as an S3Store, or a directory path (or ``file://`` URI) as a LocalStore.

    ``endpoint`` is the S3 endpoint URL (else ``AWS_ENDPOINT_URL``, else AWS); it is ignored for directories.
    """
    local = local_store(uri)
    if local is not None:
        return local
    scheme, rest = uri.split("://", 1)  # local_store took every URI without a scheme
    if scheme.lower() != "s3":
        raise StoreError(f"bad store URI {uri!r}: use s3://bucket/prefix or a directory path")
    bucket, _, prefix = rest.partition("/")
    if not bucket:
        raise StoreError(f"bad store URI {uri!r}: no bucket name")
    if not _BUCKET.match(bucket):
        raise StoreError(f"bad store URI {uri!r}: invalid bucket name {bucket!r}")
    return S3Store(bucket, prefix, endpoint)


def is_transient(exc: BaseException) -> bool:
    """Whether a later retry may cure ``exc``: the store did not answer or failed on its side (StoreUnavailable);
    not a missing key or bucket, refused credentials or a bad name."""
    return isinstance(exc, StoreUnavailable)
