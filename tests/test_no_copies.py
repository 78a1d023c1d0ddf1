"""The repository holds no copies of the public data it is tested against, and names no package registry.

DeepRacer's routes, Gazebo logs and community files are read in place from the shared folder (tests/shared_data.py);
neither the tree (tracked files and untracked ones git does not ignore) nor the wheel and sdist built from it may
carry them, whole or in part. A file counts as a copy of shared data when

* its bytes are a shared file's (sha256);
* it is a ``.npy`` array with at least ``MIN_ROWS`` rows (all of them when it has fewer) that are rows of one shared
  route, compared exactly in the file's own float dtype, or rows of a window of its columns (a centre line alone).
  Equal float64 rows do not happen by chance: a handful means the rows were copied;
* it is a text file (CSV, log, JSON, env, Markdown, Python, ...) with a run of ``MIN_LINES`` consecutive
  distinctive lines that are all lines of one shared text file. Distinctive: ``MIN_LINE_CHARS`` characters or more
  once stripped (blank lines, braces and short JSON fields never count), and in at most ``MAX_SOURCES`` shared
  files: what many independent sources write alike (a sim-trace's CSV header, DeepRacer's default
  ``"batch_size": 64,``) is the format, not anyone's data, and is skipped, while a sim-trace row (episode, step,
  position, time stamp, ...) belongs to its log alone. Lines are compared after taking a Python string literal's
  text (``"0,1,3.05,...\\n",`` is the CSV row ``0,1,3.05,...``), so rows pasted into a test are caught.
  "Consecutive" is in the repository's file, not the shared one: an excerpt of every tenth row is still a copy;
* it is a text file with a run of ``MIN_LINES`` consecutive lines of numbers that each hold at least two numbers
  of one row of one shared file (a log's line, a route's row), as they are or rounded, in any order and among
  others: a log's columns picked, reordered and rounded, or route rows pasted into a test, are copies too. Only
  precise numbers count (``MIN_DECIMALS`` decimals and ``MIN_DIGITS`` significant digits: ``7.257970`` but not
  ``1.0000``, ``0.0012`` or a lap time's ``17.75``): two of them equal to a shared row's by chance, five lines in
  a row, does not happen.

The shared folder's own notes (``SOURCES.md``) describe the data and are no public material: they are left out.
"""

from __future__ import annotations

import functools
import hashlib
import io
import re
import shutil
import subprocess
import sys
import tarfile
import zipfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from tests.shared_data import REPO, SHARED_DATA, shared_data

MIN_ROWS = 5
MIN_LINES = 5
MIN_LINE_CHARS = 20
MAX_SOURCES = 2
MIN_DIGITS = 4
MIN_DECIMALS = 4
MAX_CANDIDATES = 500  # a number that many shared values round to tells nothing (a track's length on every row)
NOTES = {"SOURCES.md"}  # the shared folder's descriptions of its data, written here, not copied from anywhere

# Package-registry hosts, assembled so that this file does not name them itself.
REGISTRY_HOSTS = [
    ".".join(parts)
    for parts in (
        ("deb", "debian", "org"),
        ("security", "debian", "org"),
        ("pypi", "org"),
        ("pypi", "python", "org"),
        ("files", "pythonhosted", "org"),
        ("registry", "npmjs", "org"),
        ("registry", "yarnpkg", "com"),
        ("archive", "ubuntu", "com"),
        ("security", "ubuntu", "com"),
    )
]

# A line of Python source that is a string literal (maybe a call's argument or a list item): its text.
_LITERAL = re.compile(r"""[rRbBuUfF]{0,2}(?P<q>"{3}|'{3}|"|')(?P<text>(?:\\.|(?!(?P=q)).)*)(?P=q)\s*[,)\]]*\s*\\?""")
_NUMBER = re.compile(r"(?<![\w.])-?\d+\.(\d+)(?![\w.])")


def tree_files() -> list[str]:
    """The repository's files: tracked, and untracked ones git does not ignore (paths relative to the root)."""
    out = subprocess.run(
        ["git", "ls-files", "-z", "-co", "--exclude-standard"], cwd=REPO, check=True, capture_output=True
    ).stdout
    return sorted({p for p in out.decode().split("\0") if p and (REPO / p).is_file()})


def as_text(data: bytes) -> list[str] | None:
    """A text file's lines; None for a binary file."""
    return None if b"\0" in data[:8192] else data.decode("utf-8", errors="replace").splitlines()


def normalize(line: str) -> str:
    line = line.strip()
    if match := _LITERAL.fullmatch(line):
        line = match["text"]
    return line.removesuffix("\\n").removesuffix("\\r").strip()


def long_lines(lines: list[str]) -> list[str]:
    """The lines of ``MIN_LINE_CHARS`` characters or more, normalized, in order."""
    return [line for line in map(normalize, lines) if len(line) >= MIN_LINE_CHARS]


def precise(token: str) -> bool:
    whole, _, decimals = token.lstrip("-").partition(".")
    return len(decimals) >= MIN_DECIMALS and len((whole + decimals).strip("0")) >= MIN_DIGITS


def precise_numbers(line: str) -> list[tuple[float, float]]:
    """The precise numbers of a line, each with how far the value it was printed from may lie (its last digit)."""
    return [(float(m[0]), 10.0 ** -len(m[1])) for m in _NUMBER.finditer(line) if precise(m[0])]


def as_float_table(data: bytes) -> np.ndarray | None:
    try:
        array = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError):
        return None
    if array.ndim != 2 or array.dtype.kind != "f" or array.dtype.itemsize < 4 or not array.size:
        return None
    return array


def row_keys(array: np.ndarray) -> list[bytes]:
    array = np.ascontiguousarray(array + 0.0)  # -0.0 as 0.0
    return [row.tobytes() for row in array]


def longest_runs(matches: Iterable[set[int]]) -> dict[int, int]:
    """For each source, the longest run of consecutive items that all match it."""
    run: dict[int, int] = {}
    longest: dict[int, int] = {}
    for sources in matches:
        run = {s: run.get(s, 0) + 1 for s in sources}
        for s, n in run.items():
            longest[s] = max(longest.get(s, 0), n)
    return longest


@dataclass
class SharedIndex:
    root: Path
    digests: dict[str, Path] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)  # the text files and routes, numbered
    lines: dict[str, set[int]] = field(default_factory=dict)  # distinctive line -> the text files holding it
    common: set[str] = field(default_factory=set)  # long lines in more than MAX_SOURCES text files
    routes: list[tuple[Path, np.ndarray]] = field(default_factory=list)
    values: np.ndarray = field(default_factory=lambda: np.empty(0))  # every precise number, sorted
    value_rows: np.ndarray = field(default_factory=lambda: np.empty(0, int))  # its row (a number in row_files)
    row_files: np.ndarray = field(default_factory=lambda: np.empty(0, int))  # each row's file (in files)
    _rows: dict[tuple[str, int], list[tuple[str, set[bytes]]]] = field(default_factory=dict)

    def name(self, path: Path) -> str:
        return str(path.relative_to(self.root))

    def route_rows(self, dtype: np.dtype, width: int) -> list[tuple[str, set[bytes]]]:
        """Each shared route's rows, or those of each window of ``width`` columns, as ``dtype`` bytes."""
        key = (dtype.str, width)
        if key not in self._rows:
            found = []
            for path, array in self.routes:
                for first in range(array.shape[1] - width + 1):
                    window = array[:, first : first + width].astype(dtype)
                    label = self.name(path)
                    if width != array.shape[1]:
                        label += f" (columns {first}-{first + width - 1})"
                    found.append((label, set(row_keys(window))))
            self._rows[key] = found
        return self._rows[key]

    def rows_holding(self, numbers: list[tuple[float, float]]) -> set[int]:
        """The files with a row that holds at least two of ``numbers`` (as printed, rounded or cut)."""
        tokens: dict[int, set[int]] = {}  # row -> which of the numbers it holds
        values: dict[int, set[int]] = {}  # row -> which of its values they are (a log repeats steer in action)
        for token, (value, step) in enumerate(numbers):
            lo = np.searchsorted(self.values, value - step * 1.000001, side="left")
            hi = np.searchsorted(self.values, value + step * 1.000001, side="right")
            if hi - lo <= MAX_CANDIDATES:
                for position in range(lo, hi):
                    row = int(self.value_rows[position])
                    tokens.setdefault(row, set()).add(token)
                    values.setdefault(row, set()).add(position)
        return {int(self.row_files[row]) for row in tokens if len(tokens[row]) >= 2 and len(values[row]) >= 2}


@functools.cache
def shared_index() -> SharedIndex:
    index = SharedIndex(SHARED_DATA)
    values: list[float] = []
    value_rows: list[int] = []
    row_files: list[int] = []
    for path in sorted(p for p in SHARED_DATA.rglob("*") if p.is_file() and p.name not in NOTES):
        data = path.read_bytes()
        index.digests.setdefault(hashlib.sha256(data).hexdigest(), path)
        number = len(index.files)
        if path.suffix == ".npy":
            if (array := as_float_table(data)) is None:
                continue
            index.files.append(path)
            index.routes.append((path, array))
            rows = [[float(v) for v in row if precise(repr(float(v)))] for row in array]
        elif (lines := as_text(data)) is not None:
            index.files.append(path)
            for line in long_lines(lines):
                index.lines.setdefault(line, set()).add(number)
            rows = [[value for value, _ in precise_numbers(line)] for line in lines]
        else:
            continue
        for row in rows:
            if len(row) >= 2:
                values += row
                value_rows += [len(row_files)] * len(row)
                row_files.append(number)
    index.common = {line for line, files in index.lines.items() if len(files) > MAX_SOURCES}
    for line in index.common:
        del index.lines[line]
    order = np.argsort(values, kind="stable")
    index.values = np.asarray(values)[order]
    index.value_rows = np.asarray(value_rows, dtype=np.int64)[order]
    index.row_files = np.asarray(row_files, dtype=np.int64)
    return index


def copied_rows(name: str, array: np.ndarray, index: SharedIndex) -> str | None:
    keys = row_keys(array)
    need = min(MIN_ROWS, len(keys))
    for label, rows in index.route_rows(array.dtype, array.shape[1]):
        if (found := sum(key in rows for key in keys)) >= need:
            return f"{name}: {found} of its {len(keys)} rows are rows of the shared {label}"
    return None


def runs_message(name: str, matches: list[set[int]], what: str, index: SharedIndex) -> str | None:
    sources = sorted((n, s) for s, n in longest_runs(matches).items() if n >= MIN_LINES)
    if not sources:
        return None
    n, source = sources[-1]
    also = f"; runs from {len(sources) - 1} other shared file(s) too" if len(sources) > 1 else ""
    return (
        f"{name}: {sum(bool(m) for m in matches)} of its {len(matches)} {what}, "
        f"{n} in a row from the shared {index.name(index.files[source])}{also}"
    )


def copied_lines(name: str, lines: list[str], index: SharedIndex) -> str | None:
    """A run of MIN_LINES consecutive distinctive lines that are all lines of one shared text file."""
    distinctive = [line for line in long_lines(lines) if line not in index.common]
    matches = [index.lines.get(line, set()) for line in distinctive]
    return runs_message(name, matches, "distinctive lines are lines of shared files", index)


def copied_numbers(name: str, lines: list[str], index: SharedIndex) -> str | None:
    """A run of MIN_LINES consecutive lines of numbers that each hold two numbers of a row of one shared file."""
    rows = [numbers for numbers in map(precise_numbers, lines) if len(numbers) >= 2]
    matches = [index.rows_holding(numbers) for numbers in rows]
    return runs_message(name, matches, "lines of precise numbers hold numbers of a shared row", index)


def copy_of_shared(name: str, data: bytes, index: SharedIndex) -> str | None:
    """Why the file ``name`` holding ``data`` is a copy of shared data (one line), or None."""
    if (same := index.digests.get(hashlib.sha256(data).hexdigest())) is not None:
        return f"{name}: byte for byte the shared {index.name(same)}"
    if name.endswith(".npy"):
        array = as_float_table(data)
        return None if array is None else copied_rows(name, array, index)
    if (lines := as_text(data)) is None:
        return None
    return copied_lines(name, lines, index) or copied_numbers(name, lines, index)


def report(copies: list[str], where: str) -> str:
    return (
        f"{len(copies)} file(s) {where} copy public data from {SHARED_DATA} (read it in place instead):\n"
        + "\n".join(f"  {c}" for c in copies)
    )


def test_tests_data_community_is_gone():
    assert not (REPO / "tests" / "data" / "community").exists(), (
        "tests/data/community holds copies of the community's files: the tests read them from "
        f"{SHARED_DATA / 'community'}"
    )


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_no_file_in_the_tree_copies_shared_data():
    shared_data()
    index = shared_index()
    copies = [c for p in tree_files() if (c := copy_of_shared(p, (REPO / p).read_bytes(), index))]
    assert not copies, report(copies, "in the repository")


def archive_members(path: Path) -> Iterator[tuple[str, bytes]]:
    if path.suffix == ".whl":
        with zipfile.ZipFile(path) as wheel:
            for info in wheel.infolist():
                if not info.is_dir():
                    yield info.filename, wheel.read(info)
    else:
        with tarfile.open(path) as sdist:
            for member in sdist.getmembers():
                if member.isfile() and (handle := sdist.extractfile(member)) is not None:
                    yield member.name, handle.read()


def test_no_file_in_the_wheel_or_sdist_copies_shared_data(tmp_path):
    shared_data()
    index = shared_index()
    # Built from a copy of the tree, so that the checkout gets no build/ or egg-info and nothing ignored comes along.
    source = tmp_path / "src"
    for name in tree_files():
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, source / name)
    dist = tmp_path / "dist"
    for hook in ("build_wheel", "build_sdist"):  # each in a fresh process, as PEP 517 front ends call them
        build = f"import sys; from setuptools import build_meta; build_meta.{hook}(sys.argv[1])"
        done = subprocess.run([sys.executable, "-c", build, str(dist)], cwd=source, capture_output=True, text=True)
        assert done.returncode == 0, f"{hook} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    archives = sorted(dist.glob("*.whl")) + sorted(dist.glob("*.tar.gz"))
    assert len(archives) == 2, archives
    copies = [
        c
        for archive in archives
        for member, data in archive_members(archive)
        if (c := copy_of_shared(f"{archive.name}:{member}", data, index))
    ]
    assert not copies, report(copies, "in the built wheel and sdist")


def npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def waypoints_py(points: np.ndarray) -> bytes:
    """A test module holding points as a Python list of (x, y), printed to 0.1 mm."""
    return ("WAYPOINTS = [\n" + "".join(f"    ({x:.4f}, {y:.4f}),\n" for x, y in points) + "]\n").encode()


def test_the_checks_catch_planted_copies():
    """The checks above find what they look for: a planted copy of each kind is reported, racer's own data is not."""
    routes = sorted(shared_data("tracks").glob("*.npy"))
    logs = sorted(shared_data("logs").rglob("*.csv"))
    assert routes and logs, "the shared folder holds no routes or sim-trace logs"
    index = shared_index()
    route, log = routes[0], logs[0]
    table = np.load(route)
    rows = log.read_text().splitlines()[1 : 1 + 3 * MIN_LINES : 3]  # every third row: an excerpt is a copy too
    fields = [row.split(",") for row in rows]  # episode,steps,X,Y,yaw,...
    picked = "".join(f"{i},{float(f[3]):.6f},{float(f[2]):.5f},{f[4]}\n" for i, f in enumerate(fields))
    planted = {
        "copy.npy": route.read_bytes(),
        "rows.npy": npy_bytes(table[::-2]),
        "centre.npy": npy_bytes(table[:, :2].astype(np.float32)),
        "excerpt.csv": ("# taken from a log\n" + "\n".join(rows) + "\n").encode(),
        "test_pasted.py": ("ROWS = [\n" + "".join(f'    "{row}\\n",\n' for row in rows) + "]\n").encode(),
        "picked.csv": ("# picked from a log\nt,y_m,x_m,heading\n" + picked).encode(),
        "test_route.py": waypoints_py(table[:, :2]),
    }
    for name, data in planted.items():
        assert copy_of_shared(name, data, index), f"the checks miss a planted copy: {name}"
    own = {
        "own.npy": npy_bytes(table[:MIN_ROWS] + 1e-3),
        "own.csv": "".join(
            f"{i},{float(f[3]) + 0.01:.6f},{float(f[2]) - 0.01:.5f}\n" for i, f in enumerate(fields)
        ).encode(),
        "few.csv": ("\n".join(rows[: MIN_LINES - 1]) + "\n").encode(),
        "test_route.py": waypoints_py(table[:, :2] + 0.01),
    }
    for name, data in own.items():
        assert copy_of_shared(name, data, index) is None, f"the checks take {name}, not a copy, for one"


def test_no_file_names_a_package_registry_host():
    """Mirrors and package indexes come from the machine's own configuration, never from a name in the tree."""
    me = Path(__file__).resolve().relative_to(REPO).as_posix()
    hosts = [host.encode() for host in REGISTRY_HOSTS]
    found = []
    for name in tree_files():
        if name == me:
            continue
        for number, line in enumerate((REPO / name).read_bytes().lower().splitlines(), 1):
            found += [f"  {name}:{number}: {host.decode()}" for host in hosts if host in line]
    message = "package-registry hosts named in the repository (take them from the machine's configuration):\n"
    assert not found, message + "\n".join(found)
