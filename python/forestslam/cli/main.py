"""Entry point: builds the typer app from one module per command and turns errors into one line."""

from __future__ import annotations

import logging
import sys

import typer

from forestslam.cli import batch, detect, evaluate, info, localize, run, simulate, tls_register

app = typer.Typer(
    name="forestslam",
    help="LiDAR SLAM, tree mapping and localization for forest machines.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

for command_module in (info, simulate, detect, run, evaluate, localize, tls_register, batch):
    command_module.register(app)


@app.callback()
def _root(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log debug messages."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Log warnings and errors only."),
) -> None:
    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    fmt = "%(levelname)s %(name)s: %(message)s"
    logging.basicConfig(level=level, format=fmt, stream=sys.stderr)


def main() -> None:
    """Run the CLI; a ForestSlamError or a bad file becomes one line on stderr and exit 1."""
    from forestslam.errors import ForestSlamError

    try:
        app(standalone_mode=False)
    except (ForestSlamError, FileNotFoundError, PermissionError, IsADirectoryError) as exc:
        print(f"forestslam: error: {exc}", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt:
        print("forestslam: interrupted", file=sys.stderr)
        sys.exit(130)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort:
        sys.exit(1)
    except Exception as exc:
        # Usage errors of typer's (vendored) click: show its message, no traceback.
        if hasattr(exc, "show") and hasattr(exc, "exit_code"):
            exc.show()
            sys.exit(exc.exit_code)
        raise


if __name__ == "__main__":
    main()
