"""``racer tracks pull``: DeepRacer's route files downloaded into the track folder, each checked against racer's
sha256 table, from real HTTP servers on 127.0.0.1 (serving ../shared's routes, a corrupted copy, a cut-off body)
and from a server that is down. Nothing half-written may be left in the track folder."""

from __future__ import annotations

import hashlib
import http.server
import os
import socket
import stat
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from sim.routes import SIMAPP_COMMIT, PullError, deepracer_route_names, pull, route_checksums
from sim.track import load_track
from tests.shared_data import SHARED_TRACKS, needs_deepracer_tracks


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # keep the test output clean
        pass


class _CutOffHandler(http.server.BaseHTTPRequestHandler):
    """Announces 25,000 bytes, sends 100, closes: a download cut off mid-way."""

    def do_GET(self) -> None:
        self.send_response(200)
        self.send_header("Content-Length", "25000")
        self.end_headers()
        self.wfile.write(b"\x93NUMPY" + b"\0" * 94)
        self.wfile.flush()
        self.close_connection = True

    def log_message(self, *args) -> None:
        pass


@contextmanager
def serve(handler) -> Iterator[str]:
    """An HTTP server on 127.0.0.1 on a free port, in a thread; yields its base URL; counts requests."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    server.requests = 0  # type: ignore[attr-defined]
    original = server.finish_request

    def counted(*args) -> None:
        server.requests += 1  # type: ignore[attr-defined]
        original(*args)

    server.finish_request = counted  # type: ignore[method-assign]
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        serve.last_requests = server.requests  # type: ignore[attr-defined]


def racer(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "racer", *args], capture_output=True, text=True, timeout=300, env=env or dict(os.environ)
    )


def folder_state(folder: Path) -> dict[str, bytes]:
    """Every file in the folder (hidden and partial ones included) with its bytes."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())} if folder.exists() else {}


# --- the table -----------------------------------------------------------------------------------------------------


def test_the_table_names_127_routes_each_with_a_sha256():
    table = route_checksums()
    assert len(table) == 127
    assert all(len(d) == 64 and int(d, 16) >= 0 for d in table.values())
    for name in ("reinvent_base", "2024_reinvent_champ_ccw", "2022_summit_speedway_cw", "Straight_track"):
        assert name in table
    assert "H_track" not in table  # a deepracer-race-data file, not a simapp route
    assert len(SIMAPP_COMMIT) == 40


@needs_deepracer_tracks
def test_the_table_is_the_sha256_of_every_simapp_route():
    # ../shared holds the simapp's bundle/routes at the commit racer cites, byte for byte.
    for name, digest in route_checksums().items():
        assert hashlib.sha256((SHARED_TRACKS / f"{name}.npy").read_bytes()).hexdigest() == digest, name


# --- pulling ------------------------------------------------------------------------------------------------------


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
@needs_deepracer_tracks
def test_pull_all_from_a_local_server_caches_127_verified_tracks_that_load(tmp_path):
    cache = tmp_path / "tracks"
    with serve(partial(_QuietHandler, directory=str(SHARED_TRACKS))) as url:
        done = racer("tracks", "pull", "--all", "--from", url, "--dir", str(cache))
        assert done.returncode == 0, done.stderr
        assert "127 pulled, 0 already there" in done.stdout
        again = racer("tracks", "pull", "--all", "--from", url, "--dir", str(cache))
    assert again.returncode == 0 and "0 pulled, 127 already there" in again.stdout
    assert serve.last_requests == 127  # the second pull downloaded nothing
    files = sorted(p.name for p in cache.iterdir())
    assert files == sorted(f"{n}.npy" for n in deepracer_route_names())  # nothing else: no partial file
    for name, digest in route_checksums().items():
        assert hashlib.sha256((cache / f"{name}.npy").read_bytes()).hexdigest() == digest
    umask = os.umask(0)
    os.umask(umask)
    # Readable as the umask allows (a folder mounted into containers), not mkstemp's 0600.
    assert stat.S_IMODE((cache / "reinvent_base.npy").stat().st_mode) == 0o666 & ~umask
    track = load_track(cache / "2024_reinvent_champ_ccw.npy")
    assert track.closed and track.length == pytest.approx(25.11, abs=0.01)


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
@needs_deepracer_tracks
def test_a_pulled_track_is_found_by_name_on_every_command(tmp_path):
    cache = tmp_path / "tracks"
    env = {**os.environ, "RACER_TRACKS_DIR": str(cache), "RACER_TRACKS_FROM": f"file://{SHARED_TRACKS}"}
    missing = racer("drive", "--track", "reInvent2019_wide_cw", "--episodes", "1", env=env)
    assert missing.returncode == 2 and "racer tracks pull reInvent2019_wide_cw" in missing.stderr
    assert racer("tracks", "pull", "reInvent2019_wide_cw", env=env).returncode == 0  # the source from the environment
    driven = racer("drive", "--track", "reInvent2019_wide_cw", "--episodes", "1", env=env)
    assert driven.returncode == 0, driven.stderr
    listed = racer("tracks", "ls", env={**env, "COLUMNS": "200"})
    assert any("reInvent2019_wide_cw" in line and "DeepRacer" in line for line in listed.stdout.splitlines())
    assert "126 DeepRacer tracks can be pulled" in listed.stdout


def test_a_tampered_file_is_refused_and_the_track_folder_is_unchanged(tmp_path):
    source = tmp_path / "mirror"
    source.mkdir()
    buf = tmp_path / "fake.npy"
    np.save(buf, np.ones((10, 6)))  # a well-formed .npy, but not reinvent_base's bytes
    (source / "reinvent_base.npy").write_bytes(buf.read_bytes())
    cache = tmp_path / "tracks"
    cache.mkdir()
    (cache / "reinvent_base.npy").write_bytes(b"the user's own file")
    before = folder_state(cache)
    with serve(partial(_QuietHandler, directory=str(source))) as url:
        done = racer("tracks", "pull", "reinvent_base", "--from", url, "--dir", str(cache))
    assert done.returncode == 2
    err = done.stderr.strip()
    assert len(err.splitlines()) == 1 and "reinvent_base.npy" in err and "sha256" in err and url in err
    assert folder_state(cache) == before


@needs_deepracer_tracks
def test_one_corrupted_route_among_good_ones_is_named_and_the_good_ones_kept(tmp_path):
    source = tmp_path / "mirror"
    source.mkdir()
    for name in ("Oval_track", "Bowtie_track", "Vegas_track"):
        data = bytearray((SHARED_TRACKS / f"{name}.npy").read_bytes())
        if name == "Bowtie_track":
            data[-3] ^= 0x01  # one bit of one coordinate
        (source / f"{name}.npy").write_bytes(bytes(data))
    cache = tmp_path / "tracks"
    with pytest.raises(PullError) as info:
        pull(["Oval_track", "Bowtie_track", "Vegas_track"], str(source), cache)
    assert "Bowtie_track.npy" in str(info.value) and "sha256" in str(info.value)
    assert sorted(folder_state(cache)) == ["Oval_track.npy", "Vegas_track.npy"]


def test_a_download_cut_off_midway_leaves_nothing(tmp_path):
    cache = tmp_path / "tracks"
    with serve(_CutOffHandler) as url, pytest.raises(PullError) as info:
        pull(["reinvent_base"], url, cache)
    message = str(info.value)
    assert "reinvent_base.npy" in message and ("partial" in message or "download failed" in message), message
    assert folder_state(cache) == {}


def test_a_server_that_is_down_is_a_clear_one_line_error(tmp_path):
    with socket.socket() as sock:  # a port nothing listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    cache = tmp_path / "tracks"
    done = racer("tracks", "pull", "Oval_track", "--from", f"http://127.0.0.1:{port}", "--dir", str(cache))
    assert done.returncode == 2
    err = done.stderr.strip()
    assert len(err.splitlines()) == 1 and f"http://127.0.0.1:{port}/Oval_track.npy: cannot connect" in err, err
    assert folder_state(cache) == {}


def test_a_missing_file_on_the_server_is_named_with_its_http_status(tmp_path):
    with serve(partial(_QuietHandler, directory=str(tmp_path))) as url, pytest.raises(PullError, match="HTTP 404"):
        pull(["Oval_track"], url, tmp_path / "tracks")


def test_an_unknown_name_fails_before_anything_is_downloaded(tmp_path):
    with serve(partial(_QuietHandler, directory=str(tmp_path))) as url:
        done = racer("tracks", "pull", "reinvent_base", "no_such_track", "--from", url, "--dir", str(tmp_path / "t"))
    assert done.returncode == 2 and "unknown DeepRacer track 'no_such_track'" in done.stderr
    assert serve.last_requests == 0
    assert not (tmp_path / "t").exists() or folder_state(tmp_path / "t") == {}


def test_pull_wants_names_or_all_not_both_nor_neither(tmp_path):
    for args in ([], ["reinvent_base", "--all"]):
        done = racer("tracks", "pull", *args, "--dir", str(tmp_path))
        assert done.returncode == 2 and "give track names or --all" in done.stderr


# --- offline, and a --from that cannot hold the routes -------------------------------------------------------------


def test_an_unreachable_download_names_the_failure_and_how_to_pull_offline(tmp_path):
    with socket.socket() as sock:  # a port nothing listens on: the download fails as it does offline
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    cache = tmp_path / "tracks"
    # No --from given: the source is the default one, here pointed (by RACER_TRACKS_FROM) at the dead port.
    env = {**os.environ, "RACER_TRACKS_FROM": f"http://127.0.0.1:{port}"}
    done = racer("tracks", "pull", "Oval_track", "reinvent_base", "--dir", str(cache), env=env)
    assert done.returncode == 2
    err = done.stderr.strip()
    assert len(err.splitlines()) == 1, err
    assert "cannot connect" in err and f"127.0.0.1:{port}" in err  # the network failure
    assert "--from PATH" in err and "offline" in err  # and the way round it
    assert folder_state(cache) == {}


def test_a_missing_file_in_a_local_folder_is_not_called_a_network_failure(tmp_path):
    source = tmp_path / "mirror"
    source.mkdir()
    (source / "Oval_track.npy").write_bytes(b"not a route")
    with pytest.raises(PullError) as info:
        pull(["reinvent_base", "Oval_track"], f"file://{source}", tmp_path / "tracks")
    message = str(info.value)
    assert "reinvent_base.npy: No such file or directory" in message, message
    assert "offline" not in message and "cannot connect" not in message


@pytest.mark.parametrize("kind", ["missing", "empty", "a file"])
def test_a_from_folder_that_cannot_hold_the_routes_is_one_error_naming_it(tmp_path, kind):
    source = tmp_path / "routes"
    if kind == "empty":
        source.mkdir()
        (source / "README.md").write_text("no routes here")
    elif kind == "a file":
        source.write_bytes(b"an archive, say")
    cache = tmp_path / "tracks"
    done = racer("tracks", "pull", "--all", "--from", str(source), "--dir", str(cache))
    assert done.returncode == 2
    err = done.stderr.strip()
    assert len(err.splitlines()) == 1, err
    assert "--from" in err and str(source) in err and "more failed" not in err, err
    assert not cache.exists()  # nothing installed, not even the folder


def test_a_from_file_url_to_a_missing_folder_is_one_error_naming_it(tmp_path):
    url = f"file://{tmp_path / 'nowhere'}"
    with pytest.raises(PullError, match="--from") as info:
        pull(["Oval_track", "reinvent_base"], url, tmp_path / "tracks")
    assert url in str(info.value) and "does not exist" in str(info.value)
    assert not (tmp_path / "tracks").exists()


def test_a_misspelt_deepracer_name_suggests_the_closest(tmp_path):
    done = racer("tracks", "pull", "reinvent_bse", "--dir", str(tmp_path / "t"))
    assert done.returncode == 2
    err = done.stderr.strip()
    assert len(err.splitlines()) == 1 and "'reinvent_bse'" in err and "did you mean 'reinvent_base'" in err, err
    with pytest.raises(PullError, match="did you mean 'reInvent2019_wide_cw'"):
        pull(["reinvent2019_wide_cw"], str(tmp_path), tmp_path / "t")  # the right name in the wrong case
