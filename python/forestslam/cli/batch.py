"""`forestslam batch`: many recordings in one command, each a Dask task, with a summary."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command(
        "batch",
        help="Run (and, with truth, evaluate) every recording of MANIFEST as one Dask task: "
        "OUT/<name>/ run directories, OUT/summary.csv, summary.md and summary.png. Recordings "
        "finished by an earlier call are kept unless --force.",
    )
    def _command(
        manifest: Path = typer.Argument(..., metavar="MANIFEST", help="YAML with recordings:"),
        out: Path = typer.Option(..., "--out", help="Output directory."),
        workers: int | None = typer.Option(
            None, "--workers", help="Local worker processes (default: one per core)."
        ),
        scheduler: str | None = typer.Option(
            None, "--scheduler", help="Address of a running Dask scheduler, tcp://HOST:PORT."
        ),
        force: bool = typer.Option(False, "--force", help="Redo finished recordings too."),
        no_progress: bool = typer.Option(False, "--no-progress", help="No progress lines."),
    ) -> None:
        import logging
        import os
        import sys

        from forestslam.batch import load_manifest, run_batch
        from forestslam.errors import ProcessingError

        if not logging.getLogger().isEnabledFor(logging.DEBUG):  # Dask's chatter only with -v
            # read when distributed is imported, here and in the worker processes it starts
            os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")
        recordings = load_manifest(manifest)
        try:
            result = run_batch(
                recordings,
                out,
                workers=workers,
                scheduler=scheduler,
                force=force,
                progress=not no_progress,
            )
        except KeyboardInterrupt:  # typer would turn it into a return value, lost by main()
            print("forestslam: interrupted; the same command resumes the batch", file=sys.stderr)
            sys.exit(130)
        ok = len(result.rows) - len(result.failed)
        print(
            f"{ok} of {len(result.rows)} recordings ok ({result.skipped} finished earlier), "
            f"{len(result.failed)} failed, in {result.wall_s:.1f} s -> {out / 'summary.md'}"
        )
        if result.failed:
            names = ", ".join(r["name"] for r in result.failed)
            raise ProcessingError(f"{len(result.failed)} recording(s) failed: {names}")
