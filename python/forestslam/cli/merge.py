"""`forestslam merge RUN_A RUN_B --out DIR`: one tree map of two runs, in A's frame."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command(
        "merge",
        help="Place run B's tree map in run A's frame (global localization plus refinement) and "
        "write the merged trees (fused DBH, observation counts, source a/b/both) and both "
        "trajectories in A's frame: trees.csv, trees.geojson, trajectory_a.tum, "
        "trajectory_b.tum, merge.yaml, map.png.",
    )
    def _command(
        run_a: Path = typer.Argument(
            ..., metavar="RUN_A", help="Run directory whose frame is kept."
        ),
        run_b: Path = typer.Argument(..., metavar="RUN_B", help="Run directory placed into A."),
        out: Path = typer.Option(..., "--out", help="Output directory."),
        overwrite: bool = typer.Option(
            False, "--overwrite", help="Replace the outputs of another command in OUT."
        ),
    ) -> None:
        from forestslam.job import Job
        from forestslam.multisession.runs import merge_runs

        inputs = check_merge_inputs(run_a, run_b)
        meta = {"run_a": str(run_a), "run_b": str(run_b)}
        with Job("merge", out, meta, inputs=inputs, overwrite=overwrite) as job:
            s = merge_runs(run_a, run_b, out)
            job.summary = {k: s[k] for k in ("x", "y", "yaw_deg", "matched_trees") if k in s}
        print(
            f"B placed in A at x {s['x']:.3f} m, y {s['y']:.3f} m, yaw {s['yaw_deg']:.2f} deg "
            f"({s['agreeing_queries']} of {s['queries']} queries agree, {s['matched_trees']} "
            f"trees matched, rms {s['rms_m'] * 100:.1f} cm); {s['trees']['merged']} trees -> {out}"
        )


def check_merge_inputs(run_a: Path, run_b: Path) -> list[Path]:
    """The files merge reads (so --out cannot replace them); refuses A == B and a run that is
    still running; warns about a run that did not complete (its last checkpoint is merged)."""
    import logging

    from forestslam.errors import InputError
    from forestslam.job import LOCK_NAME, run_status

    log = logging.getLogger("forestslam.merge")
    for name, run in (("RUN_A", run_a), ("RUN_B", run_b)):
        if not run.is_dir():
            raise InputError(f"{name} {run}: not a run directory")
    if run_a.resolve() == run_b.resolve():
        raise InputError(f"RUN_A and RUN_B are the same directory ({run_a}); give two runs")
    for run in (run_a, run_b):
        status, error = run_status(run)
        if status == "running" and _locked(run / LOCK_NAME):
            raise InputError(f"{run}: still running (run.yaml: status running); merge it after")
        if status not in (None, "complete"):
            why = f" ({error})" if error else ""
            log.warning(
                "%s/run.yaml says status: %s%s; merging its last checkpoint", run, status, why
            )
    return [run / f for run in (run_a, run_b) for f in ("trees.csv", "trajectory.tum")]


def _locked(path: Path) -> bool:
    """True when a live process holds the job lock at `path` (a killed job's is free)."""
    import fcntl
    import os

    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return False
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
