"""`forestslam evaluate` (not wired yet)."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    @app.command("evaluate", help="(not available yet)")
    def _command() -> None:
        from forestslam.errors import ForestSlamError

        raise ForestSlamError("'evaluate' is not available in this build yet")
