"""`forestslam info INPUT [--topic T] [--json]`: what a bag, folder or cloud file holds."""

from __future__ import annotations

from pathlib import Path

import typer


def summarize(path: Path, topic: str | None, rate_hz: float) -> dict:
    """Read every scan once and return the summary `info` prints (also usable from Python)."""
    import numpy as np

    from forestslam.io import open_source

    source = open_source(path, topic, rate_hz)
    stamps, counts, spans, rings = [], [], [], 0
    for scan in source.scans():
        stamps.append(scan.stamp)
        counts.append(len(scan))
        if scan.time is not None and len(scan):
            spans.append(float(scan.time.max() - scan.time.min()))
        if scan.ring is not None and len(scan):
            rings = max(rings, int(scan.ring.max()) + 1)
    counts_arr = np.asarray(counts, dtype=np.int64)
    duration = float(max(stamps) - min(stamps)) if stamps else 0.0
    stats = source.stats
    return {
        "input": str(path),
        "format": source.format,
        "topics": [
            {"name": t.name, "type": t.msgtype, "messages": t.count} for t in source.topics()
        ],
        "topic": source.topic,
        "scans": len(counts),
        "duration_s": duration,
        "rate_hz": (len(counts) - 1) / duration if duration > 0 else None,
        "points_min": int(counts_arr.min()) if len(counts) else 0,
        "points_median": float(np.median(counts_arr)) if len(counts) else 0.0,
        "points_max": int(counts_arr.max()) if len(counts) else 0,
        "fields": source.fields() if len(source) else {},
        "time_span_s": float(np.median(spans)) if spans else None,
        "rings": rings or None,
        "skipped": stats.skipped,
        "lost_bytes": stats.lost_bytes,
        "damaged_chunks": stats.damaged_chunks,
        "degraded": dict(stats.degraded),
        "warnings": stats.warnings,
    }


def _text(info: dict) -> str:
    lines = [f"input:    {info['input']}", f"format:   {info['format']}"]
    if info["topics"]:
        lines.append("topics:")
        width = max(len(t["name"]) for t in info["topics"])
        for t in info["topics"]:
            mark = "*" if t["name"] == info["topic"] else " "
            lines.append(f" {mark} {t['name']:<{width}}  {t['type']}  {t['messages']} msgs")
    rate = f"{info['rate_hz']:.2f} Hz" if info["rate_hz"] else "-"
    lines += [
        f"scans:    {info['scans']}" + (f" (topic {info['topic']})" if info["topic"] else ""),
        f"duration: {info['duration_s']:.3f} s",
        f"rate:     {rate}",
        "points:   finite per scan min {} / median {:g} / max {}".format(
            info["points_min"], info["points_median"], info["points_max"]
        ),
        "fields:   " + (", ".join(f"{k} {v}" for k, v in info["fields"].items()) or "-"),
    ]
    if info["time_span_s"] is not None:
        lines.append(f"sweep:    per-point time spans {info['time_span_s'] * 1e3:.1f} ms (median)")
    if info["rings"]:
        lines.append(f"rings:    {info['rings']}")
    if info["skipped"] or info["lost_bytes"] or info["damaged_chunks"]:
        lines.append(
            f"damage:   {info['skipped']} messages skipped, {info['damaged_chunks']} damaged "
            f"chunks, {info['lost_bytes']} bytes lost (see the warnings above)"
        )
    if info["degraded"]:
        counts = ", ".join(f"{k} {v}" for k, v in sorted(info["degraded"].items()))
        lines.append(f"checks:   {counts} (see the warnings above)")
    return "\n".join(lines)


def register(app: typer.Typer) -> None:
    @app.command("info", help="Show what a bag, cloud folder or cloud file holds.")
    def _command(
        input_path: Path = typer.Argument(
            ..., metavar="INPUT", help="ROS1 .bag, ROS2 .mcap/.db3/folder, cloud folder or file."
        ),
        topic: str = typer.Option(None, "--topic", "-t", help="PointCloud2 topic to read."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
        rate_hz: float = typer.Option(
            10.0, "--rate", help="Scan rate (Hz) for files that carry no timestamps."
        ),
    ) -> None:
        import json

        from forestslam.errors import InputError

        try:
            info = summarize(input_path, topic, rate_hz)
        except (OSError, ValueError, EOFError) as exc:
            raise InputError(f"{input_path}: cannot read ({exc})") from None
        if as_json:
            typer.echo(json.dumps(info))
        else:
            typer.echo(_text(info))
