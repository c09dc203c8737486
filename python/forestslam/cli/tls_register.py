"""`forestslam tls-register` (not wired yet)."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    @app.command("tls-register", help="(not available yet)")
    def _command() -> None:
        from forestslam.errors import ForestSlamError

        raise ForestSlamError("'tls-register' is not available in this build yet")
