"""The batch figure: recordings side by side, one panel per metric (summary.png)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

# (column(s), panel title, scale to the plotted unit)
_PANELS = (
    (("ate_m",), "ATE RMSE [m]", 1.0),
    (("rpe_pct",), "RPE over 10 m [%]", 1.0),
    (("recall", "precision"), "tree recall / precision", 1.0),
    (("dbh_mae_m", "dbh_bias_m"), "DBH MAE / bias [cm]", 100.0),
    (("scans_per_s",), "throughput [scans/s]", 1.0),
)


def plot_summary(path: Path, rows: list[dict]) -> None:
    """Horizontal bars per recording and metric; failed recordings are labelled in red and
    metrics a recording does not have (no truth, no trees) are left empty."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from forestslam.io.atomic import atomic_write

    y = np.arange(len(rows))
    height = max(2.5, 0.35 * len(rows) + 1.2)
    fig, axes = plt.subplots(1, len(_PANELS), figsize=(3.2 * len(_PANELS), height), sharey=True)
    for ax, (columns, title, scale) in zip(axes, _PANELS, strict=True):
        width = 0.8 / len(columns)
        for j, col in enumerate(columns):
            values = np.array([np.nan if r.get(col) is None else r[col] for r in rows], float)
            offset = (j - (len(columns) - 1) / 2) * width
            ax.barh(
                y + offset, values * scale, height=width, label=col if len(columns) > 1 else None
            )
        ax.set_title(title, fontsize=9)
        ax.axvline(0.0, color="0.5", lw=0.5)
        ax.grid(axis="x", alpha=0.3)
        if len(columns) > 1:
            ax.legend(fontsize=7)
    labels = [r["name"] if r["status"] == "ok" else f"{r['name']} (failed)" for r in rows]
    axes[0].set_yticks(y, labels, fontsize=8)
    axes[0].invert_yaxis()
    for label, row in zip(axes[0].get_yticklabels(), rows, strict=True):
        if row["status"] != "ok":
            label.set_color("tab:red")
    failed = [r for r in rows if r["status"] != "ok"]
    fig.suptitle(f"{len(rows) - len(failed)} ok, {len(failed)} failed (red)", fontsize=10)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=100), mode="wb")
    plt.close(fig)
