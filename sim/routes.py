"""DeepRacer's route files: where racer keeps them, and the verified download that puts them there.

racer ships no DeepRacer track. ``racer tracks pull NAME`` downloads a route file from the community simapp's
``bundle/routes/`` at the commit racer follows (:data:`SIMAPP_COMMIT`, the one whose ``track_data.py`` racer reads
routes as), checks it against the sha256 racer computed for each of the 127 names (``deepracer_routes.sha256``
beside this module, in ``sha256sum`` format: ``sha256sum -c`` checks a folder with it), and writes it into the track
folder (:func:`tracks_dir`) under a temporary name that becomes the real one only once the whole file is verified:
a mismatch, a partial download or a server that is down leaves the folder as it was.

``--from`` (or ``RACER_TRACKS_FROM``) takes another base URL (``http://``, ``https://``, ``file://``) or a local
folder: a DRfC or simapp checkout's ``bundle/routes``, a mirror, or a test server. Files are checked the same way,
whatever the source. A local source (a folder or ``file://``) that does not exist, or holds none of the routes asked
for, is one error naming it before anything is read; a download that cannot reach its server says how to pull offline.
"""

from __future__ import annotations

import hashlib
import os
import urllib.error
import urllib.parse
import urllib.request
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path

from common.errors import UserError, did_you_mean
from common.files import write_atomically

SIMAPP_COMMIT = "01f5f015fd852f952b351643898d4beb4f36494b"
"""aws-deepracer-community/deepracer-simapp, 2026-07-18 ("Apply Upstream v1.2.4"): the routes and route reading
racer follows."""
DEFAULT_SOURCE = (
    f"https://raw.githubusercontent.com/aws-deepracer-community/deepracer-simapp/{SIMAPP_COMMIT}/bundle/routes"
)
TRACKS_DIR_ENV = "RACER_TRACKS_DIR"
"""Environment variable naming the folder of DeepRacer tracks (default ``$XDG_CACHE_HOME/racer/tracks`` or
``~/.cache/racer/tracks``). It may point at a DRfC or simapp checkout's routes folder: racer then reads them there."""
SOURCE_ENV = "RACER_TRACKS_FROM"
"""Environment variable giving ``racer tracks pull`` another source (a base URL or a local folder)."""
OFFLINE_HINT = (
    "to pull offline, give a local folder of DeepRacer .npy routes (a simapp or DRfC checkout's bundle/routes): "
    "`racer tracks pull NAME... --from PATH`"
)
"""Said after a download that could not reach its server: the one way to get routes without a network."""
MAX_ROUTE_BYTES = 1 << 20  # the largest route is 25 kB; anything far larger is not a route file
_TIMEOUT_S = 30.0


class PullError(UserError):
    """A route that could not be pulled; the message names it, the source and what went wrong."""


class _Unreachable(PullError):
    """A download that never reached its server, or lost it mid-way (offline, DNS, refused, reset, timed out)."""


def tracks_dir() -> Path:
    """The folder racer reads DeepRacer tracks from by name, and ``racer tracks pull`` writes to."""
    explicit = os.environ.get(TRACKS_DIR_ENV)
    if explicit:
        return Path(explicit).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "racer" / "tracks"


@cache
def route_checksums() -> dict[str, str]:
    """Every DeepRacer route name racer knows, with the sha256 of its file at :data:`SIMAPP_COMMIT`."""
    text = (resources.files("sim") / "deepracer_routes.sha256").read_text()
    table = {}
    for line in text.splitlines():
        digest, filename = line.split(maxsplit=1)
        table[filename.lstrip("*").removesuffix(".npy")] = digest
    return table


def deepracer_route_names() -> list[str]:
    """The 127 DeepRacer route names that can be pulled, sorted."""
    return sorted(route_checksums())


def cached_route_names(folder: Path | None = None) -> list[str]:
    """Names of the ``.npy`` files in the track folder, sorted (empty when it does not exist)."""
    folder = folder or tracks_dir()
    return sorted(p.stem for p in folder.glob("*.npy")) if folder.is_dir() else []


def pull_command(name: str) -> str:
    """The command that gets one DeepRacer track, for error messages."""
    return f"racer tracks pull {name}"


@dataclass(frozen=True)
class Pulled:
    """What pulling one route did."""

    name: str
    path: Path
    fresh: bool
    """False when the folder already held the verified file (nothing was downloaded)."""


def pull(names: list[str], source: str | None = None, folder: Path | None = None, jobs: int = 8) -> list[Pulled]:
    """Download and verify ``names`` into ``folder``; raise one PullError naming every route that failed.

    An unknown name fails before anything is downloaded. A route already in the folder with the right checksum is
    not downloaded again; one with another content is replaced, once the new file is verified.
    """
    table = route_checksums()
    unknown = [n for n in names if n not in table]
    if unknown:
        guess = did_you_mean(unknown[0], table)
        raise PullError(
            f"unknown DeepRacer track {unknown[0]!r}: {guess + ' ' if guess else ''}`racer tracks ls` lists the "
            f"{len(table)} that can be pulled"
        )
    source = source or os.environ.get(SOURCE_ENV) or DEFAULT_SOURCE
    _check_source(source, names)
    folder = folder or tracks_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PullError(f"cannot create the track folder {str(folder)!r}: {exc.strerror or exc}") from None
    with ThreadPoolExecutor(max_workers=max(1, min(jobs, len(names) or 1))) as pool:
        outcomes = list(pool.map(lambda n: _pull_one(n, table[n], source, folder), dict.fromkeys(names)))
    failed = [o for o in outcomes if isinstance(o, PullError)]
    if failed:
        more = f" (and {len(failed) - 1} more failed; {len(outcomes) - len(failed)} pulled)" if len(failed) > 1 else ""
        offline = f"; {OFFLINE_HINT}" if any(isinstance(f, _Unreachable) for f in failed) else ""
        raise PullError(f"{failed[0]}{more}{offline}")
    return [o for o in outcomes if isinstance(o, Pulled)]


def _local_path(source: str) -> Path | None:
    """The local path a source or location names (a path or a ``file://`` URL); None for a remote one."""
    if source.startswith("file://"):
        return Path(urllib.request.url2pathname(urllib.parse.urlparse(source).path))
    return None if "://" in source else Path(source).expanduser()


def _check_source(source: str, names: list[str]) -> None:
    """A PullError naming ``--from`` and the source if it cannot hold the routes: a scheme racer cannot read, or a
    local folder that does not exist or holds none of them.

    Checked once, up front: otherwise every route would fail on its own and the user would read one path's error
    and "126 more failed" instead of the one thing to fix."""
    fix = "give a folder of DeepRacer .npy routes (a simapp or DRfC checkout's bundle/routes) or an http(s) URL"
    folder = _local_path(source)
    if folder is None:
        if not source.startswith(("http://", "https://")):
            raise PullError(f"--from {source!r}: cannot pull from that scheme; {fix}")
        return
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise PullError(f"--from {source!r} {what}: {fix}")
    if names and not any((folder / f"{n}.npy").is_file() for n in names):
        wanted = f"no {names[0]}.npy" if len(names) == 1 else f"none of the {len(names)} routes asked for"
        raise PullError(f"--from {source!r} holds {wanted}: {fix}")


def _pull_one(name: str, digest: str, source: str, folder: Path) -> Pulled | PullError:
    """Pull one route; the error returned rather than raised, so the others still run."""
    target = folder / f"{name}.npy"
    if target.is_file() and _sha256(target.read_bytes()) == digest:
        return Pulled(name, target, fresh=False)
    where = _location(source, f"{name}.npy")
    try:
        data = _read(where)
    except PullError as exc:
        return exc
    got = _sha256(data)
    if got != digest:
        return PullError(
            f"{where}: sha256 {got[:12]}... is not {name}'s ({digest[:12]}...): a changed, truncated or wrong "
            f"file ({len(data)} bytes); the track folder is unchanged"
        )
    try:
        write_atomically(target, data, f".{target.name}.{uuid.uuid4().hex}.partial")
    except OSError as exc:
        return PullError(f"{target}: cannot write ({exc.strerror or exc}); the track folder is unchanged")
    return Pulled(name, target, fresh=True)


def _location(source: str, filename: str) -> str:
    if "://" in source:
        return f"{source.rstrip('/')}/{filename}"
    return str(Path(source).expanduser() / filename)


def _read(where: str) -> bytes:
    """The bytes at a URL or a local path; a PullError naming it if they cannot be had whole."""
    local = _local_path(where)
    if local is not None:  # file:// read as a path too: a missing file is not a network failure
        try:
            with open(local, "rb") as fh:
                return fh.read(MAX_ROUTE_BYTES + 1)
        except OSError as exc:
            raise PullError(f"{where}: {exc.strerror or exc}") from None
    try:
        with urllib.request.urlopen(where, timeout=_TIMEOUT_S) as response:  # noqa: S310 (schemes checked by _check_source)
            data = response.read(MAX_ROUTE_BYTES + 1)
            expected = response.headers.get("Content-Length")
    except urllib.error.HTTPError as exc:
        raise PullError(f"{where}: HTTP {exc.code} {exc.reason}") from None
    except urllib.error.URLError as exc:
        raise _Unreachable(f"{where}: cannot connect ({exc.reason})") from None
    except (OSError, ValueError) as exc:  # a reset, a timeout or a cut-off body (http.client.IncompleteRead)
        raise _Unreachable(f"{where}: download failed ({type(exc).__name__}: {exc})") from None
    if expected is not None and expected.isdigit() and int(expected) != len(data):
        raise PullError(f"{where}: partial download ({len(data)} of {expected} bytes)")
    return data


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()
