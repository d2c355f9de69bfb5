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


OUTAGE_S = 3.0  # a gap between fixes longer than this is marked as an outage


def plot_run(drive: list[dict[str, Any]], estimates: list[dict[str, Any]], path: Path,
             graph: RoadGraph | None = None, title: str = "navsvc run") -> None:
    """Write the plot to ``path`` (PNG), metres east and north of the start: the roads,
    truth when the drive has it, raw GPS, the fused track and the matched positions; the
    start, the end and each GPS outage (fused positions in it drawn in orange)."""
    truth = [r for r in drive if r.get("kind") == "truth"]
    gps = [r for r in drive if r.get("kind") == "gps"]
    fused_records = [r for r in estimates if r.get("fused_lat") is not None]
    first = next(iter(truth or gps or fused_records), None)
    if first is None:
        raise NavsvcError("nothing to plot: no truth, GPS or positions")
    lon, lat = ("fused_lon", "fused_lat") if "fused_lat" in first and "lat" not in first \
        else ("lon", "lat")
    frame = graph.frame if graph is not None else LocalFrame.for_point(first[lon], first[lat])
    truth_xy, gps_xy = _xy(truth, frame), _xy(gps, frame)
    fused = _xy(fused_records, frame, "fused_lat", "fused_lon")
    drawn = np.vstack([a for a in (truth_xy, gps_xy, fused) if len(a)])
    origin = drawn[0]
    lo, hi = drawn.min(axis=0) - 150.0, drawn.max(axis=0) + 150.0
    fig, ax = plt.subplots(figsize=(10, 10), dpi=120)
    if graph is not None:
        _draw_roads(ax, graph, lo, hi, origin)
    if len(truth_xy):
        t = truth_xy - origin
        ax.plot(t[:, 0], t[:, 1], color="black", linewidth=1.2, label="truth", zorder=2)
    if len(gps_xy):
        g = gps_xy - origin
        ax.scatter(g[:, 0], g[:, 1], s=6, color="tab:red", alpha=0.6, label="raw GPS",
                   zorder=3)
    if len(fused):
        f = fused - origin
        ax.plot(f[:, 0], f[:, 1], color="tab:blue", linewidth=1.0, label="fused", zorder=4)
        _mark_outages(ax, gps, fused_records, f)
        ax.scatter(f[0, 0], f[0, 1], marker="o", s=80, color="white", edgecolor="black", zorder=7,
                   label="start")
        ax.scatter(f[-1, 0], f[-1, 1], marker="s", s=80, color="black", zorder=7, label="end")
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
    ax.set_title(title)
    try:
        fig.savefig(path, format="png", bbox_inches="tight")
    except OSError as exc:
        raise NavsvcError(f"{path}: cannot write the plot ({exc.strerror})") from None
    finally:
        plt.close(fig)


def _draw_roads(ax: Any, graph: RoadGraph, lo: np.ndarray, hi: np.ndarray,
                origin: np.ndarray) -> None:
    for edge in graph.edges:
        inside = np.all((edge.coords >= lo) & (edge.coords <= hi), axis=1)
        if inside.any():
            c = edge.coords - origin
            ax.plot(c[:, 0], c[:, 1], color="0.85", linewidth=2.5, zorder=1)


def _mark_outages(ax: Any, gps: list[dict[str, Any]], fused_records: list[dict[str, Any]],
                  fused_xy: np.ndarray) -> None:
    """The fused track inside each gap of the GPS longer than OUTAGE_S, in orange."""
    times = sorted(r["t"] for r in gps)
    t = np.array([r["t"] for r in fused_records])
    label = "GPS outage"
    for start, end in zip(times[:-1], times[1:]):
        if end - start <= OUTAGE_S:
            continue
        inside = (t > start) & (t < end)
        if inside.any():
            ax.plot(fused_xy[inside, 0], fused_xy[inside, 1], color="tab:orange",
                    linewidth=2.0, zorder=6, label=label)
            label = "_"
