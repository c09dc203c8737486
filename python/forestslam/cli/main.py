"""Entry point: builds the typer app from one module per command and turns errors into one line.

The error boundary: a ForestSlamError, any OSError (with its path), a usage error or even an
unexpected exception ends the program with one line on stderr and a non-zero exit; only
`--debug` shows a traceback.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading

import typer

from forestslam.cli import (
    batch,
    detect,
    evaluate,
    info,
    localize,
    merge,
    run,
    simulate,
    tls_register,
)

app = typer.Typer(
    name="forestslam",
    help="LiDAR SLAM, tree mapping and localization for forest machines.",
    no_args_is_help=True,
    add_completion=True,  # --install-completion: commands, options and choices in the shell
    pretty_exceptions_enable=False,
)

COMMANDS = (info, simulate, detect, run, evaluate, localize, tls_register, merge, batch)
for command_module in COMMANDS:
    command_module.register(app)

_debug = False


def _print_version(value: bool) -> None:
    if value:
        import forestslam

        print(f"forestslam {forestslam.__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log debug messages."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Log warnings and errors only."),
    debug: bool = typer.Option(False, "--debug", help="Show the traceback of an error."),
    version: bool = typer.Option(
        False, "--version", callback=_print_version, is_eager=True, help="Print the version."
    ),
) -> None:
    global _debug
    _debug = debug
    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    fmt = "%(levelname)s %(name)s: %(message)s"
    logging.basicConfig(level=level, format=fmt, stream=sys.stderr)


def describe_os_error(exc: OSError) -> str:
    """'PATH: reason' (both paths of a rename) for an OSError, whatever raised it."""
    reason = exc.strerror or str(exc)
    paths = [str(p) for p in (exc.filename, exc.filename2) if p is not None]
    return f"{' -> '.join(paths)}: {reason}" if paths else reason


def _fail(message: str, code: int = 1) -> None:
    print(f"forestslam: error: {message}", file=sys.stderr)
    sys.exit(code)


_stop_signal: int | None = None  # the signal that stopped the job (typer swallows the exception)


def _stop(signum, frame) -> None:
    """SIGINT / SIGTERM: stop where the job is, as Ctrl-C does (its run.yaml: `interrupted`)."""
    from forestslam.errors import Terminated

    global _stop_signal
    _stop_signal = signum
    name = signal.Signals(signum).name
    raise Terminated(f"stopped by {name}") if signum != signal.SIGINT else KeyboardInterrupt(name)


# The thread pools of the numerical libraries (OpenBLAS under numpy/SciPy, OpenMP, MKL). A job
# is one sequential per-scan loop, and BLAS only multiplies (N,3) clouds by 3x3 rotations (the
# map outputs): extra threads win little and spin while they wait, taking CPU from the sensor
# driver on a 2-core field computer (`make run`: 8 % more CPU and 4x the wall time on a loaded
# machine with OpenBLAS's default pool). A batch runs one process per core (Dask's nanny sets the
# same variables in its workers).
LIBRARY_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def limit_library_threads() -> None:
    """One thread per numerical library unless the user set the variable; effective only
    before numpy loads, so main() calls it first (the CLI modules import numpy lazily)."""
    for var in LIBRARY_THREAD_VARS:
        os.environ.setdefault(var, "1")


def main() -> None:
    """Run the CLI; every error becomes one line on stderr and a non-zero exit. SIGTERM stops a
    job like Ctrl-C (exit 128 + signal number)."""
    global _stop_signal
    limit_library_threads()
    _stop_signal = None
    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous = {sig: signal.signal(sig, _stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        _main()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _main() -> None:
    from forestslam.errors import ForestSlamError

    try:
        code = app(standalone_mode=False)  # returns an exit code instead of raising typer.Exit
        if _stop_signal is not None:  # typer turned the KeyboardInterrupt into exit code 130
            raise KeyboardInterrupt
        sys.exit(code if isinstance(code, int) else 0)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort:
        sys.exit(1)
    except KeyboardInterrupt:
        sig = _stop_signal or signal.SIGINT
        print(f"forestslam: interrupted ({signal.Signals(sig).name})", file=sys.stderr)
        sys.exit(128 + sig)
    except Exception as exc:
        if _debug:
            raise
        if isinstance(exc, ForestSlamError):
            _fail(str(exc))
        if isinstance(exc, OSError):
            _fail(describe_os_error(exc))
        if isinstance(exc, UnicodeDecodeError):  # a reader met a binary file where text belongs
            _fail(f"an input file is not UTF-8 text ({exc.reason} at byte {exc.start})")
        # Usage errors of typer's (vendored) click: show its message.
        if hasattr(exc, "show") and hasattr(exc, "exit_code"):
            exc.show()
            sys.exit(exc.exit_code)
        _fail(
            f"internal error: {type(exc).__name__}: {exc} "
            "(please report it; `forestslam --debug ...` shows the traceback)",
            code=2,
        )


if __name__ == "__main__":
    main()
