"""The batch summary: OUT/summary.csv (one row per recording, job.COLUMNS) and OUT/summary.md."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from forestslam.batch.job import COLUMNS

# how each number is printed in summary.md (summary.csv keeps full precision)
_FORMATS = {
    "scans_per_s": "{:.1f}",
    "ate_m": "{:.3f}",
    "rpe_pct": "{:.2f}",
    "recall": "{:.3f}",
    "precision": "{:.3f}",
    "dbh_mae_m": "{:.4f}",
    "dbh_bias_m": "{:+.4f}",
}


def write_summary(out: Path, rows: list[dict], wall_s: float) -> None:
    """summary.csv and summary.md into `out` (atomically); rows in manifest order."""
    from forestslam.io.atomic import atomic_write_text

    atomic_write_text(out / "summary.csv", summary_csv(rows))
    atomic_write_text(out / "summary.md", summary_markdown(rows, wall_s))


def summary_csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if row.get(k) is None else row[k] for k in COLUMNS})
    return buf.getvalue()


def summary_markdown(rows: list[dict], wall_s: float) -> str:
    ok = [r for r in rows if r["status"] == "ok"]
    scans = sum(r["scans"] or 0 for r in ok)
    lines = [
        "# forestslam batch",
        "",
        f"{len(ok)} of {len(rows)} recordings ok, {len(rows) - len(ok)} failed; "
        f"{scans} scans; this call took {wall_s:.1f} s (recordings finished earlier were kept).",
        "",
        "| " + " | ".join(COLUMNS) + " |",
        "|" + "|".join("---" for _ in COLUMNS) + "|",
    ]
    for row in rows:
        cells = [_cell(k, row.get(k)) for k in COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _cell(key: str, value) -> str:
    if value is None or value == "":
        return ""
    if key in _FORMATS:
        return _FORMATS[key].format(value)
    return str(value).replace("|", "\\|")
