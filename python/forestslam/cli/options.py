"""The options every scan job shares (`run`, `localize`, `tls-register`, `detect`), written once
so they read and behave the same in each command; their values go to forestslam.job (ScanWindow
checks the window, Job the output directory)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

Start = Annotated[
    int, typer.Option("--start", help="Skip this many scans first (they are not decoded).")
]
MaxScans = Annotated[int | None, typer.Option("--max-scans", help="Process at most N scans.")]
Topic = Annotated[str | None, typer.Option("--topic", help="PointCloud2 topic of a bag.")]
ConfigFile = Annotated[Path | None, typer.Option("--config", help="YAML configuration.")]
NoProgress = Annotated[bool, typer.Option("--no-progress", help="No progress bar.")]
Overwrite = Annotated[
    bool, typer.Option("--overwrite", help="Replace the outputs of another command in OUT.")
]
OutDir = Annotated[Path, typer.Option("--out", help="Output directory.")]
