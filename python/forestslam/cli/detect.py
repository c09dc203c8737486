"""`forestslam detect INPUT [--scan K] --sensor P --out trees.csv [--png view.png]`."""

from __future__ import annotations

from pathlib import Path

import typer

from forestslam.cli.options import MaxScans, NoProgress, Start, Topic


def register(app: typer.Typer) -> None:
    @app.command(
        "detect",
        help="Detect tree stems and their DBH in one scan, every scan, or one map / TLS cloud "
        "(sensor frame). Writes trees.csv (id,x,y,z,dbh_m; with a leading `scan` column when "
        "several scans are processed; empty dbh_m = no accepted fit, or one whose expected "
        "error is above 2 cm).",
    )
    def _command(
        input: Path = typer.Argument(..., help="Bag (.bag/.mcap), folder or cloud file."),
        sensor: str | None = typer.Option(
            None,
            "--sensor",
            help="Profile name or YAML (vlp16, map, ...); default: identified from the data.",
        ),
        out: Path = typer.Option(..., "--out", help="Output CSV of the detected trees."),
        scan: int | None = typer.Option(None, "--scan", help="Process only scan K (0-based)."),
        png: Path | None = typer.Option(
            None, "--png", help="PNG of the breast-height slice with detections (last scan)."
        ),
        topic: Topic = None,
        config: Path | None = typer.Option(None, "--config", help="YAML (perception section)."),
        start: Start = 0,
        max_scans: MaxScans = None,
        no_progress: NoProgress = False,
        breast_height_z: float | None = typer.Option(
            None,
            "--breast-height-z",
            help="Breast height (z in the input frame) for every stem. Default: 1.3 m above the "
            "local ground; without ground, above the stem's lowest point, or the middle of a "
            "stem piece shorter than the band (a breast-height slice).",
        ),
    ) -> None:
        from forestslam.config import load_config
        from forestslam.errors import InputError
        from forestslam.io import write_trees_csv
        from forestslam.job import Progress, check_output_file
        from forestslam.sensors import load_profile

        profile = load_profile(sensor) if sensor is not None else None
        cfg = load_config(config).perception
        window = _window(scan, start, max_scans)
        check_output_file(out)
        packets = profile.packet_config() if profile is not None else None
        _, stream, count = window.open(input, topic, packets)  # scans before it not decoded
        if profile is None:
            from forestslam.sensors.identify import identify_stream

            profile, stream = identify_stream(stream)
        bar = Progress(count, "scan", "detect", enabled=not no_progress and count != 1)
        try:
            tally = _detect_all(stream, window.start, profile, cfg, breast_height_z, bar)
        finally:
            bar.close()
        if tally.n_scans == 0:
            what = f"scan {scan}" if scan is not None else "any scan"
            raise InputError(f"{input}: has no {what}")
        columns = tally.columns()
        write_trees_csv(out, columns)
        _report(tally, columns, out)
        if breast_height_z is not None and len(columns["id"]) == 0:
            print(
                f"no stem has points within {cfg.diameter.band_max_half_m:g} m of "
                f"--breast-height-z {breast_height_z:g}: no DBH there"
            )
        if png is not None and tally.last is not None:
            from forestslam.perception.plotting import plot_detections

            k, sc, stems = tally.last
            plot_detections(
                sc.points, stems, png, title=f"{input.name} scan {k}: {len(stems)} stems"
            )
            print(f"breast-height slice -> {png}")


def _window(scan: int | None, start: int, max_scans: int | None):
    """The scan window: one scan K (--scan), else --start / --max-scans."""
    from forestslam.errors import InputError
    from forestslam.job import ScanWindow

    if scan is not None and scan < 0:
        raise InputError(f"--scan must be >= 0, not {scan}")
    if scan is not None and (start or max_scans is not None):
        raise InputError("--scan K is one scan: give it without --start / --max-scans")
    return ScanWindow(scan, 1) if scan is not None else ScanWindow(start, max_scans)


class _Tally:
    """The stems of every scan as table rows, the breast-height sources and the time spent."""

    def __init__(self, n_sources: int) -> None:
        import numpy as np

        self.rows: dict[str, list] = {k: [] for k in ("scan", "id", "x", "y", "z", "dbh_m")}
        self.n_scans, self.last, self.total_ms = 0, None, 0.0
        self.sources = np.zeros(n_sources, dtype=np.int64)

    def add(self, k: int, sc, stems, ms: float) -> None:
        import numpy as np

        self.sources += np.bincount(stems.breast_source, minlength=len(self.sources))
        self.total_ms += ms
        self.n_scans += 1
        self.last = (k, sc, stems)
        rows = self.rows
        rows["scan"] += [k] * len(stems)
        rows["id"] += stems.ids.tolist()
        rows["x"] += stems.xy[:, 0].tolist()
        rows["y"] += stems.xy[:, 1].tolist()
        rows["z"] += stems.z.tolist()
        rows["dbh_m"] += stems.reported_dbh().tolist()

    def columns(self) -> dict:
        """The trees.csv columns (no `scan` column for a single scan)."""
        import numpy as np

        rows = self.rows
        columns = {
            "scan": np.asarray(rows["scan"], dtype=np.int64),
            "id": np.asarray(rows["id"], dtype=np.int64),
            **{c: np.asarray(rows[c], dtype=np.float64) for c in ("x", "y", "z", "dbh_m")},
        }
        if self.n_scans == 1:
            del columns["scan"]
        return columns


def _detect_all(stream, first: int, profile, cfg, breast_height_z, bar) -> _Tally:
    import time

    from forestslam.perception import detect
    from forestslam.perception.stems import BREAST_HEIGHT_SOURCES

    tally = _Tally(len(BREAST_HEIGHT_SOURCES))
    for k, sc in enumerate(stream, start=first):
        bar.update(1)
        t0 = time.perf_counter()
        if k == first and breast_height_z is not None:
            _check_breast_height(sc.points, breast_height_z)
        stems = detect(sc, profile, cfg, breast_height_z)
        tally.add(k, sc, stems, (time.perf_counter() - t0) * 1e3)
    return tally


def _check_breast_height(points, z: float) -> None:
    """--breast-height-z outside the first scan's heights (centimetres, another frame) is
    refused: no stem has points there, and a slice outside the cloud is no measurement."""
    import numpy as np

    from forestslam.errors import InputError

    heights = points[:, 2][np.isfinite(points[:, 2])]
    if np.isfinite(z) and len(heights) and not heights.min() <= z <= heights.max():
        raise InputError(
            f"--breast-height-z {z:g} is outside the cloud's heights (z {heights.min():.2f} .. "
            f"{heights.max():.2f} in the input frame); give it in metres in that frame"
        )


def _report(tally: _Tally, columns: dict, out: Path) -> None:
    import numpy as np

    from forestslam.perception.stems import BREAST_HEIGHT_SOURCES

    n_trees = len(columns["id"])
    n_dbh = int(np.isfinite(columns["dbh_m"]).sum())
    print(
        f"{n_trees} stems ({n_dbh} with DBH) in {tally.n_scans} scan(s), "
        f"{tally.total_ms / tally.n_scans:.1f} ms per scan -> {out}"
    )
    if n_trees:
        used = ", ".join(
            f"{BREAST_HEIGHT_SOURCES[i]} ({n})" for i, n in enumerate(tally.sources) if n
        )
        print(f"breast height (1.3 m above the base) from: {used}")
