"""Fixtures shared by several test files."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.fixture
def run_main(capsys, monkeypatch):
    """The console entry in this process (fast): returns (exit code, stdout, stderr)."""
    from forestslam.cli.main import main

    def run(*args) -> subprocess.CompletedProcess:
        monkeypatch.setattr(sys, "argv", ["forestslam", *map(str, args)])
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = exc.code
        out = capsys.readouterr()
        return subprocess.CompletedProcess(args, code, out.out, out.err)

    return run
