"""One recording of a batch, as one Dask task: run it, evaluate it, mark it finished.

The run directory `OUT/<name>/` is what `forestslam run` writes, plus `metrics.json` and
`errors.png` when the entry has `truth`, plus `batch.json` written last: the manifest entry it was
made from and its summary row. A recording counts as finished (and is skipped on the next call)
only when batch.json matches the current entry, run.yaml says `status: complete` and, with truth,
metrics.json exists. Anything else (killed worker, interrupted batch, edited entry or
configuration) is redone from the start.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from pathlib import Path

from forestslam.batch.manifest import Recording
from forestslam.errors import ForestSlamError

log = logging.getLogger(__name__)

COLUMNS = (
    "name",
    "status",
    "error",
    "scans",
    "scans_per_s",
    "ate_m",
    "rpe_pct",
    "trees",
    "recall",
    "precision",
    "dbh_mae_m",
    "dbh_bias_m",
)
MARKER = "batch.json"
# Errors of the recording itself (missing, corrupt or unusable data): failed at once. Anything
# else is left to Dask, which retries the task once (`retries=1`) before it counts as failed.
RECORDING_ERRORS = (ForestSlamError, OSError)


def run_pipeline(rec: Recording, run_dir: Path):
    """The one call into the pipeline, made as `forestslam run` makes it; returns its RunSummary.

    Adapter: when the runner's interface changes, only this function follows it."""
    from forestslam import runner

    return runner.run(
        rec.input,
        rec.sensor,
        run_dir,
        mode=rec.mode,
        config_path=rec.config,
        start=rec.start,
        max_scans=rec.max_scans,
        progress=False,
        prior_map=rec.prior_map,
    )


def process_recording(rec: Recording, out_root: str) -> dict:
    """The Dask task: one summary row (COLUMNS). Errors of the recording give a `failed` row."""
    run_dir = Path(out_root) / rec.name
    run_dir.mkdir(parents=True, exist_ok=True)
    for stale in (MARKER, "metrics.json", "errors.png"):  # never mistake old results for new
        (run_dir / stale).unlink(missing_ok=True)
    try:
        summary = run_pipeline(rec, run_dir)
        row = empty_row(rec.name, "ok")
        row.update(scans=summary.scans, scans_per_s=summary.scans_per_s, trees=summary.trees)
        if rec.truth is not None:
            row.update(_metric_columns(_evaluate(run_dir, rec.truth)))
    except RECORDING_ERRORS as exc:
        log.info("%s failed: %s", rec.name, one_line(exc))
        return failed_row(rec.name, one_line(exc))
    _write_marker(run_dir, rec, row)
    return row


def finished_row(rec: Recording, out_root: Path) -> dict | None:
    """The stored row of a finished recording whose entry is unchanged, else None."""
    import yaml

    run_dir = out_root / rec.name
    try:
        marker = json.loads((run_dir / MARKER).read_text())
        run_yaml = yaml.load((run_dir / "run.yaml").read_text(), Loader=_yaml_loader())
    except (OSError, ValueError, yaml.YAMLError):
        return None
    if marker.get("entry") != fingerprint(rec):
        log.info("%s: manifest entry or configuration changed since it ran: redoing it", rec.name)
        return None
    complete = (run_yaml or {}).get("summary", {}).get("status") == "complete"
    if not complete or (rec.truth is not None and not (run_dir / "metrics.json").is_file()):
        return None
    return marker.get("row")


def fingerprint(rec: Recording) -> dict:
    """The entry plus the configuration file's content: a change to either redoes the run."""
    entry = rec.to_dict()
    if rec.config is not None and rec.config.is_file():
        entry["config_sha256"] = hashlib.sha256(rec.config.read_bytes()).hexdigest()
    return entry


def empty_row(name: str, status: str, error: str = "") -> dict:
    row: dict = dict.fromkeys(COLUMNS)
    row.update(name=name, status=status, error=error)
    return row


def failed_row(name: str, error: str) -> dict:
    return empty_row(name, "failed", error)


def one_line(exc: BaseException) -> str:
    """`Type: first line of the message` (only the message for forestslam's own errors)."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if isinstance(exc, ForestSlamError) and text:
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _evaluate(run_dir: Path, truth: Path) -> dict:
    from forestslam.evaluation.report import evaluate_run

    return evaluate_run(run_dir, truth)


def _metric_columns(metrics: dict) -> dict:
    traj = metrics.get("trajectory", {})
    trees = metrics.get("trees") or {}
    return {
        "ate_m": _number(traj.get("ate_rmse_m")),
        "rpe_pct": _number(traj.get("rpe_percent_10m")),
        "recall": _number(trees.get("recall")),
        "precision": _number(trees.get("precision")),
        "dbh_mae_m": _number(trees.get("dbh_mae_m")),
        "dbh_bias_m": _number(trees.get("dbh_bias_m")),
    }


def _number(value) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def _write_marker(run_dir: Path, rec: Recording, row: dict) -> None:
    from forestslam.io.atomic import atomic_write_text

    text = json.dumps({"entry": fingerprint(rec), "row": row}, indent=1)
    atomic_write_text(run_dir / MARKER, text)


def _yaml_loader():
    import yaml

    return getattr(yaml, "CSafeLoader", yaml.SafeLoader)
