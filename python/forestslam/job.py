"""The skeleton every job shares (`run`, `localize`, `tls-register`, `batch`, ...): the scan
window, progress, checkpoints, `run.yaml` and the output directory (`detect`: see below).

A job owns its output directory while it runs:

- **Lock.** ``OUT/.forestslam.lock`` is held (``flock``) for the whole run, so a second job into
  the same ``--out`` fails at once, naming the running one. The kernel drops the lock when its
  process dies, even by ``kill -9``, so a stale lock of a dead process is taken over.
- **Earlier outputs.** A job never leaves an earlier run's files beside its own. Before it starts,
  the files an earlier job wrote there (the ``outputs`` its ``run.yaml`` lists, plus the known
  output names of that command) are removed when the earlier job was the same command (a re-run
  replaces, e.g. in another ``--mode``); the outputs of a *different* command are refused unless
  ``overwrite`` (``--overwrite``), so a mistyped ``--out`` cannot delete another result. Files
  forestslam did not write are never touched; an input inside the set to remove is refused.
- **run.yaml** says ``status: running`` until the end, then ``complete``, ``failed`` (with the
  error) or ``interrupted``; it lists the job's ``outputs``. It is rewritten atomically at every
  checkpoint, so a killed job leaves a valid one.

``detect`` writes one file (``--out trees.csv``), not a directory: it uses the window, the progress
and ``check_output_file`` but no Job, so no lock and no run.yaml; its CSV is written once, at the
end and atomically, so a killed ``detect`` leaves no partial table (and nothing to resume).
"""

from __future__ import annotations

import fcntl
import itertools
import logging
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from forestslam.errors import InputError

log = logging.getLogger(__name__)

LOCK_NAME = ".forestslam.lock"
META_NAME = "run.yaml"
# Files each command writes (besides run.yaml); an earlier run's are removed by a re-run even
# when its run.yaml is missing or lists fewer (a kill before the first checkpoint).
KNOWN_OUTPUTS: dict[str, tuple[str, ...]] = {
    "run": (
        "odometry.tum",
        "trajectory.tum",
        "trees.csv",
        "trees.geojson",
        "map.png",
        "timing.json",
        "ground.ply",
        "dtm.npz",
        "dtm.csv",
        "dtm.png",
        "map.laz",
        "trees.gpkg",
        "metrics.json",  # `forestslam evaluate DIR` of the earlier run: stale with a new one
        "errors.png",
    ),
    "localize": ("localization.json", "localization.tum"),
    "tls-register": (
        "trajectory.tum",
        "plot.laz",
        "trees.csv",
        "coverage.json",
        "unmerged.csv",
        "plot.png",
    ),
    # a batch's own files; the recording folders beside them are kept (resumed) by the batch
    "batch": ("summary.csv", "summary.md", "summary.png"),
    "merge": (
        "trees.csv",
        "trees.geojson",
        "trajectory_a.tum",
        "trajectory_b.tum",
        "merge.yaml",
        "map.png",
    ),
}


# --------------------------------------------------------------------------------- paths
def check_output_path(path: str | Path, what: str = "--out") -> Path:
    """`path` as a directory to write into (created): a path that is a file, or lies inside a
    file, or cannot be created is one InputError naming it."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{what} {path}: is a file, not a directory")
    for parent in path.parents:
        if parent.exists() and not parent.is_dir():
            raise InputError(f"{what} {path}: {parent} is a file, not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{what} {path}: cannot create the directory ({exc.strerror})") from exc
    if not os.access(path, os.W_OK | os.X_OK):
        raise InputError(f"{what} {path}: the directory is not writable")
    return path


def check_output_file(path: str | Path, what: str = "--out") -> Path:
    """`path` as a file to write (its folder created): a directory, or a folder that is (or lies
    inside) a file, is one InputError naming it."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{what} {path}: is a directory, not a file")
    for parent in path.parents:
        if parent.exists() and not parent.is_dir():
            raise InputError(f"{what} {path}: {parent} is a file, not a directory")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{what} {path}: cannot create its folder ({exc.strerror})") from exc
    return path


# --------------------------------------------------------------------------------- window
@dataclass(frozen=True)
class ScanWindow:
    """`start` scans skipped (undecoded where the reader can), then at most `max_scans`."""

    start: int = 0
    max_scans: int | None = None

    def __post_init__(self) -> None:
        if self.start < 0:
            raise InputError(f"--start must be >= 0, not {self.start}")
        if self.max_scans is not None and self.max_scans < 1:
            raise InputError(f"--max-scans must be >= 1, not {self.max_scans}")

    def count(self, total: int | None) -> int | None:
        """Scans the window holds of a source of `total` (None: unknown)."""
        if total is None:
            return self.max_scans
        left = max(0, total - self.start)
        return left if self.max_scans is None else min(left, self.max_scans)

    def open(self, input_path: str | Path, topic: str | None = None, packets=None):
        """(stream, scans, count): the reader's stream (stats), the window's scans of it and
        their number (None when the source cannot tell). `packets`: how raw Velodyne packets
        are decoded (a sensor profile's `packet_config()`)."""
        from forestslam.io import read_scans

        stream = read_scans(input_path, topic, start=self.start, packets=packets)
        total = len(stream) if hasattr(stream, "__len__") else None
        return stream, itertools.islice(stream, self.max_scans), self.count(total)

    def meta(self) -> dict:
        return {"start": self.start, "max_scans": self.max_scans}


# --------------------------------------------------------------------------------- progress
class Progress:
    """A tqdm bar on a terminal; in a log (stderr not a terminal) one status line every
    `interval_s` seconds and one at the end, instead of a redraw per update."""

    def __init__(
        self,
        total: int | None,
        unit: str = "scan",
        desc: str = "",
        enabled: bool = True,
        interval_s: float = 10.0,
        stream=None,
    ) -> None:
        self.total, self.unit, self.desc = total, unit, desc
        self.enabled, self.interval_s = enabled, interval_s
        self.stream = stream or sys.stderr
        self.n, self.postfix = 0, {}
        self._t0 = self._last = time.monotonic()
        self._bar = None
        if enabled and self.stream.isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=total, unit=unit, desc=desc or None, dynamic_ncols=True)

    def update(self, n: int = 1, **postfix: Any) -> None:
        self.n += n
        self.postfix.update(postfix)
        if self._bar is not None:
            self._bar.update(n)
            if postfix:
                self._bar.set_postfix(self.postfix, refresh=False)
        elif self.enabled and time.monotonic() - self._last >= self.interval_s:
            self._line()

    def _line(self) -> None:
        self._last = time.monotonic()
        elapsed = self._last - self._t0
        done = f"{self.n}/{self.total}" if self.total else f"{self.n}"
        rate = self.n / elapsed if elapsed > 0 else 0.0
        extra = "".join(f", {k} {v}" for k, v in self.postfix.items())
        name = f"{self.desc}: " if self.desc else ""
        print(f"{name}{done} {self.unit}s, {rate:.1f}/s{extra}", file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        elif self.enabled and self.n:
            self._line()
        self.enabled = False


# --------------------------------------------------------------------------------- job
def _read_meta(path: Path) -> dict | None:
    """The run.yaml a forestslam job wrote at `path` (a mapping with `summary.status`), else
    None (missing, unreadable, or some other file of that name)."""
    import yaml

    try:
        loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml: 7x less CPU
        data = yaml.load(path.read_text(encoding="utf-8"), Loader=loader)
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None
    ours = isinstance(data, dict) and isinstance(data.get("summary"), dict)
    return data if ours and "status" in data["summary"] else None


def run_status(out_dir: str | Path) -> tuple[str | None, str | None]:
    """(status, error) of the job that wrote `out_dir`/run.yaml; (None, None) without one."""
    meta = _read_meta(Path(out_dir) / META_NAME)
    if meta is None:
        return None, None
    return str(meta["summary"]["status"]), meta["summary"].get("error")


MALLOC_KEEP_BYTES = 256 << 20  # freed heap memory glibc keeps for reuse (M_TRIM_THRESHOLD)
MALLOC_MMAP_BYTES = 32 << 20  # blocks from this size are mapped on their own (M_MMAP_THRESHOLD)


def keep_freed_memory() -> bool:
    """Let glibc's malloc keep freed memory for the next scan instead of returning it to the
    kernel: a job allocates and frees arrays of the same sizes every scan, and each block given
    back had to be faulted in, zeroed, again (sys time: 0.32-0.44 -> 0.19-0.24 s CPU over the
    sample's 417 scans, 35 % fewer page faults, +8 MB resident). A no-op (False) off glibc.
    Set for the whole process: a job is the process's work."""
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library the process already runs on
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    return bool(mallopt(m_mmap_threshold, MALLOC_MMAP_BYTES)) and bool(
        mallopt(m_trim_threshold, MALLOC_KEEP_BYTES)
    )


class Job:
    """One job writing into one output directory; use as a context manager::

        with Job("run", out, meta={...}, inputs=[bag]) as job:
            ...  # job.checkpoint(summary) now and then
            job.summary = {...}

    On entry the directory is checked, locked and cleared of an earlier run's outputs, and
    run.yaml says `running`; on exit run.yaml records the outcome (an exception is re-raised).
    """

    def __init__(
        self,
        command: str,
        out_dir: str | Path,
        meta: dict | None = None,
        inputs: Iterable[str | Path | None] = (),
        overwrite: bool = False,
        resume: bool = False,
    ) -> None:
        self.command = command
        self.resume = resume  # an earlier run of the same command keeps its files (batch)
        self.out = Path(out_dir)
        self.meta = dict(meta or {})
        self.inputs = [Path(p) for p in inputs if p is not None and not _is_object(p)]
        self.overwrite = overwrite
        self.summary: dict = {}
        self.status = "running"
        self.error: str | None = None
        self._lock_fd: int | None = None
        self._foreign: set[str] = set()

    # ---------------------------------------------------------------- claim / release
    def __enter__(self) -> Job:
        keep_freed_memory()
        check_output_path(self.out)
        self._lock()
        try:
            kept = self._clear_earlier_outputs()
            from forestslam.io.atomic import remove_stale_temporaries

            if remove_stale_temporaries(self.out):
                log.info("%s: removed temporaries left by an earlier, killed run", self.out)
            self._foreign = {p.name for p in self.out.iterdir()} - {LOCK_NAME} - kept
            self.write_meta()
        except BaseException:
            self._unlock()
            raise
        return self

    def __exit__(self, kind, exc, tb) -> bool:
        if kind is None:
            self.status = "complete"
        elif issubclass(kind, KeyboardInterrupt):
            self.status, self.error = "interrupted", str(exc) or "interrupted (Ctrl-C)"
        else:
            self.status, self.error = "failed", f"{kind.__name__}: {exc}"
        try:
            self.write_meta()
        finally:
            self._unlock()
        return False

    def _lock(self) -> None:
        path = self.out / LOCK_NAME
        while True:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 400).decode(errors="replace").strip() or "another process"
                os.close(fd)
                raise InputError(
                    f"--out {self.out}: in use by a running forestslam job ({holder}); wait for "
                    "it to end or choose another --out"
                ) from None
            # The holder may have removed the file between our open and flock: lock the file
            # that is at the path now.
            try:
                same = os.stat(path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"pid {os.getpid()}, forestslam {self.command}, since {_now()}\n".encode())
        self._lock_fd = fd

    def _unlock(self) -> None:
        if self._lock_fd is None:
            return
        try:
            (self.out / LOCK_NAME).unlink(missing_ok=True)
        except OSError:
            pass
        os.close(self._lock_fd)  # closing releases the flock
        self._lock_fd = None

    def _clear_earlier_outputs(self) -> set[str]:
        """Remove an earlier run's outputs; returns those kept (`resume`: the same command)."""
        earlier = _read_meta(self.out / META_NAME)
        mine = set(KNOWN_OUTPUTS.get(self.command, ())) | {META_NAME}
        if earlier is None:  # files of our names, but no run.yaml of a job accounts for them
            command, names = None, mine
        else:
            command = str(earlier.get("command", "run"))  # older run.yaml: only `run` wrote one
            names = mine | set(KNOWN_OUTPUTS.get(command, ()))
            listed = earlier.get("outputs")
            names |= {n for n in listed if _is_plain_name(n)} if isinstance(listed, list) else set()
        present = sorted(n for n in names if (self.out / n).exists() or (self.out / n).is_symlink())
        if not present:
            return set()
        if self.resume and (command == self.command or earlier is None):
            return names  # only our own names without a run.yaml: an older batch, resumed
        if command != self.command and not self.overwrite:
            shown = ", ".join(present[:6]) + (", ..." if len(present) > 6 else "")
            whose = f"an earlier `forestslam {command}`" if command else "no forestslam run.yaml"
            raise InputError(
                f"--out {self.out}: holds files of {whose} ({shown}); choose another --out, "
                "or pass --overwrite to replace them"
            )
        for name in present:
            if any(_same_or_inside(p, self.out / name) for p in self.inputs):
                raise InputError(
                    f"--out {self.out}: the input {self.out / name} would be replaced by this "
                    "run's outputs; choose another --out"
                )
        for name in present:
            target = self.out / name
            if target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)
            else:
                target.unlink(missing_ok=True)
        log.info("%s: removed %d files of the earlier run: %s", self.out, len(present), present)
        return set()

    # ---------------------------------------------------------------- run.yaml
    def outputs(self) -> list[str]:
        """Files this job has written into the directory so far."""
        if not self.out.is_dir():
            return []
        names = {p.name for p in self.out.iterdir()} - self._foreign - {LOCK_NAME}
        return sorted(n for n in names if not (n.startswith(".") and n.endswith(".tmp")))

    def write_meta(self) -> None:
        import yaml

        from forestslam.io.atomic import atomic_write_text

        summary = {**_plain(self.summary), "status": self.status}
        if self.error is not None:
            summary["error"] = self.error
        doc = {"command": self.command, **_plain(self.meta), "summary": summary}
        doc["outputs"] = sorted(set(self.outputs()) | {META_NAME})
        dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # libyaml: 4x less CPU, same text
        atomic_write_text(self.out / META_NAME, yaml.dump(doc, Dumper=dumper, sort_keys=False))

    def checkpoint(self, write_outputs: Callable[[], None] | None = None) -> None:
        """Write the outputs (if given), then run.yaml with the current summary."""
        if write_outputs is not None:
            write_outputs()
        self.write_meta()


class Checkpoints:
    """Due once at every `every`-th processed item (>= 1, from the validated config); asking
    again with the same count (an item that failed) is not due again."""

    def __init__(self, every: int) -> None:
        if every < 1:
            raise InputError(f"checkpoint interval must be >= 1, not {every}")
        self.every, self._last = every, 0

    def due(self, n: int) -> bool:
        if n <= self._last or n % self.every:
            return False
        self._last = n
        return True


def _plain(value: Any) -> Any:
    """Plain YAML types of a meta / summary value (numpy scalars, tuples, paths)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "item") and callable(value.item):  # numpy scalar
        return value.item()
    return value


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


def _is_object(p: Any) -> bool:
    return not isinstance(p, str | os.PathLike)


def _is_plain_name(name: Any) -> bool:
    return isinstance(name, str) and name not in ("", ".", "..") and "/" not in name


def _same_or_inside(path: Path, target: Path) -> bool:
    try:
        path, target = path.resolve(), target.resolve()
    except OSError:
        return False
    return path == target or target in path.parents
