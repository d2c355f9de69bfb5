"""A run drawn over the map: raw GPS, fused track, output position and truth (PNG)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only, no display

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from navsvc.errors import NavsvcError  # noqa: E402
from roadgraph import LocalFrame, RoadGraph  # noqa: E402


def _xy(records: list[dict[str, Any]], frame: LocalFrame, lat: str = "lat",
        lon: str = "lon") -> np.ndarray:
    if not records:
        return np.zeros((0, 2))
    return frame.coords_to_local(np.array([(r[lon], r[lat]) for r in records]))


def plot_run(drive: list[dict[str, Any]], estimates: list[dict[str, Any]], path: Path,
             graph: RoadGraph | None = None) -> None:
    """Write the plot to ``path`` (PNG); metres east and north of the drive's start."""
    truth = [r for r in drive if r.get("kind") == "truth"]
    gps = [r for r in drive if r.get("kind") == "gps"]
    frame = graph.frame if graph is not None else \
        LocalFrame.for_point(truth[0]["lon"], truth[0]["lat"])
    truth_xy = _xy(truth, frame)
    origin = truth_xy[0]
    fig, ax = plt.subplots(figsize=(10, 10), dpi=120)
    lo, hi = truth_xy.min(axis=0) - 150.0, truth_xy.max(axis=0) + 150.0
    if graph is not None:
        for edge in graph.edges:
            inside = np.all((edge.coords >= lo) & (edge.coords <= hi), axis=1)
            if not inside.any():
                continue
            c = edge.coords - origin
            ax.plot(c[:, 0], c[:, 1], color="0.85", linewidth=2.5, zorder=1)
    t = truth_xy - origin
    ax.plot(t[:, 0], t[:, 1], color="black", linewidth=1.2, label="truth", zorder=2)
    g = _xy(gps, frame) - origin
    ax.scatter(g[:, 0], g[:, 1], s=6, color="tab:red", alpha=0.6, label="raw GPS", zorder=3)
    fused = _xy(estimates, frame, "fused_lat", "fused_lon") - origin
    ax.plot(fused[:, 0], fused[:, 1], color="tab:blue", linewidth=1.0, label="fused",
            zorder=4)
    matched = [r for r in estimates if r.get("edge")]
    if matched:
        m = _xy(matched, frame) - origin
        ax.scatter(m[:, 0], m[:, 1], s=5, color="tab:green", label="matched", zorder=5)
    ax.set_xlim(lo[0] - origin[0], hi[0] - origin[0])
    ax.set_ylim(lo[1] - origin[1], hi[1] - origin[1])
    ax.set_aspect("equal")
    ax.set_xlabel("east of start [m]")
    ax.set_ylabel("north of start [m]")
    ax.legend(loc="upper right")
    ax.set_title("navsvc run against truth")
    try:
        fig.savefig(path, format="png", bbox_inches="tight")
    except OSError as exc:
        raise NavsvcError(f"{path}: cannot write the plot ({exc.strerror})") from None
    finally:
        plt.close(fig)
