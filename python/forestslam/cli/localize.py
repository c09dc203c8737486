"""`forestslam localize`: global localization in a prior tree map along a sequence."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer

from forestslam.cli.options import ConfigFile, MaxScans, NoProgress, OutDir, Overwrite, Start, Topic

Gravity = Literal["stems", "reference", "none"]  # how a tree table's frames are levelled


_RETRY_HELP = (
    "When a query is rejected, retry it on up to this many of the last frames (> N), at "
    "least localization.retry_keyframe_distance_m (3 m) apart, aggregated by odometry, and "
    "when still rejected a last time on up to localization.retry_last_frames (7); every look "
    "is tested at the significance level spent across the looks. Each query records `retried`, "
    "`looks` and the frames of its answer. Default: localization.retry_frames (5; off when "
    "N >= 5); 0: no retry. Scans only: a tree table's frames are queried one by one."
)


def register(app: typer.Typer) -> None:
    @app.command(
        "localize",
        help="Find the sensor pose in a prior tree map (saved map .npz, tree CSV with x,y"
        "[,dbh_m], map cloud or another mapper's tree tables) by Delaunay triangle stars: a "
        "query every K scans from the last N scans (aggregated with odometry), or every K-th "
        "frame of a tree table (TreeManagerState_<k>.csv + trajectory.txt, or a packed "
        "trees.csv[.gz]; levelled by the stems' axes). Writes OUT/localization.json (every "
        "query) and OUT/localization.tum (accepted queries: pose in the map frame).",
    )
    def _command(
        input_path: Path = typer.Argument(
            ..., metavar="INPUT", help="Bag, folder, cloud file or tree table (dir or file)."
        ),
        map_path: Path = typer.Option(
            ...,
            "--map",
            help="Map file (.npz), tree CSV (x,y[,dbh_m]), map cloud (.laz/.ply...) or tree "
            "table with its trajectory.",
        ),
        sensor: str | None = typer.Option(
            None, "--sensor", help="Sensor profile name or YAML file (not for tree tables)."
        ),
        out: OutDir = ...,
        frames: int = typer.Option(1, "--frames", help="Scans aggregated per query (N)."),
        retry_frames: int | None = typer.Option(
            None,
            "--retry-frames",
            help=_RETRY_HELP,
        ),
        every: int = typer.Option(1, "--every", help="A query every K scans."),
        keyframe_distance: float | None = typer.Option(
            None,
            "--keyframe-distance-m",
            help="Aggregate frames at least this far apart (wider view); default: consecutive.",
        ),
        config: ConfigFile = None,
        topic: Topic = None,
        start: Start = 0,
        max_scans: MaxScans = None,
        save_map: Path | None = typer.Option(
            None, "--save-map", help="Also save the map (e.g. built from a CSV) as .npz."
        ),
        no_progress: NoProgress = False,
        overwrite: Overwrite = False,
        gravity: Gravity = typer.Option(
            "stems",
            "--gravity",
            help="Tree tables: level each frame by its stems' axes (stems), the table's "
            "trajectory (reference) or not at all (none).",
        ),
    ) -> None:
        from forestslam.io.tree_tables import is_tree_table

        tree_map = _load_map(map_path, config, save_map)
        if is_tree_table(input_path):
            _ignored_sensor(sensor, input_path)
            _ignored_retry(retry_frames, input_path)
            _localize_table(
                input_path, tree_map, out, every, config, gravity, start, max_scans, overwrite
            )
            return
        _localize_scans(
            input_path,
            tree_map,
            sensor,
            out,
            frames=frames,
            every=every,
            config_path=config,
            topic=topic,
            start=start,
            max_scans=max_scans,
            progress=not no_progress,
            keyframe_distance_m=keyframe_distance,
            overwrite=overwrite,
            retry_frames=retry_frames,
        )


def _ignored_sensor(sensor: str | None, input_path: Path) -> None:
    if sensor is not None:
        import logging

        logging.getLogger("forestslam.localize").warning(
            "--sensor %s ignored: %s is a tree table (no scans)", sensor, input_path
        )


def _ignored_retry(retry_frames: int | None, input_path: Path) -> None:
    if retry_frames:
        import logging

        logging.getLogger("forestslam.localize").warning(
            "--retry-frames %d ignored: %s is a tree table (one frame per query)",
            retry_frames,
            input_path,
        )


def _localize_scans(input_path: Path, tree_map, sensor: str | None, out: Path, **options) -> None:
    """Queries from the scans of a bag, folder or cloud (run_localization's options)."""
    from forestslam.errors import InputError

    if sensor is None:
        raise InputError("--sensor is needed for a bag, folder or cloud input")
    from forestslam.localization.runner import run_localization

    r = run_localization(input_path, tree_map, sensor, out, **options)
    retried = [q for q in r.queries if q["retried"]]
    retry = (
        f" ({sum(q['accepted'] for q in retried)} of them on a retry with more frames; "
        f"{len(retried)} retried)"
        if retried
        else ""
    )
    print(
        f"{r.scans} scans, {len(r.queries)} queries, {r.accepted} accepted{retry}, "
        f"median {r.median_query_ms:.2f} ms per query ({tree_map}) -> {r.out_dir}"
    )


def _load_map(map_path: Path, config: Path | None, save_map: Path | None):
    """The prior tree map (localization section of --config), saved as .npz if asked."""
    from forestslam.errors import InputError
    from forestslam.localization import load_map

    loc_config = None
    if config is not None:
        from forestslam.config import load_config

        loc_config = load_config(config).localization
    tree_map = load_map(map_path, loc_config)
    if len(tree_map) < 3:
        raise InputError(f"--map {map_path}: {len(tree_map)} trees; localization needs 3 or more")
    if save_map is not None:
        print(f"map saved to {tree_map.save(save_map)}")
    return tree_map


def _localize_table(
    input_path, tree_map, out, every, config, gravity, start, max_scans, overwrite
) -> None:
    """Queries from the frames of another mapper's tree table."""
    from forestslam.localization.tables import run_table_localization

    r = run_table_localization(
        input_path,
        tree_map,
        out,
        every=every,
        config_path=config,
        gravity=gravity,
        start=start,
        max_queries=max_scans,
        overwrite=overwrite,
    )
    print(
        f"{len(r.queries)} tree-table queries, {r.accepted} accepted, median "
        f"{r.median_query_ms:.2f} ms per query ({tree_map}) -> {r.out_dir}"
    )
