"""`forestslam evaluate`: trajectory and tree-map errors of a run against simulator truth."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command(
        "evaluate",
        help="Compare a run directory with a truth directory (trajectory.tum, trees.csv): "
        "writes DIR/metrics.json and DIR/errors.png and prints a table.",
    )
    def _command(
        run_dir: Path = typer.Argument(..., metavar="DIR", help="Output directory of a run."),
        truth: Path = typer.Option(..., "--truth", help="Truth directory of the simulator."),
        gate_m: float = typer.Option(0.5, "--gate-m", help="Tree matching gate."),
        min_dbh_m: float = typer.Option(0.1, "--min-dbh-m", help="Smallest evaluated tree."),
        max_dist_m: float = typer.Option(15.0, "--max-dist-m", help="Region around the path."),
        json_out: bool = typer.Option(False, "--json", help="Print metrics.json instead."),
    ) -> None:
        import json
        import sys

        from forestslam.evaluation.report import evaluate_run, format_table
        from forestslam.job import run_status

        status, error = run_status(run_dir)
        if status not in (None, "complete"):
            why = f" ({error})" if error else ""
            print(
                f"forestslam: warning: {run_dir}/run.yaml says status: {status}{why}; "
                "scoring the outputs as of its last checkpoint",
                file=sys.stderr,
            )
        m = evaluate_run(run_dir, truth, gate_m=gate_m, min_dbh_m=min_dbh_m, max_dist_m=max_dist_m)
        print(json.dumps(m, indent=1) if json_out else format_table(m))
