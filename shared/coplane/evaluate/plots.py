"""The paper's figures from `coplane eval` runs (matplotlib, written as PNG files)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes

from coplane.evaluate.metrics import AccuracyStats, enu_errors
from coplane.evaluate.runner import MethodRun
from coplane.geo import ecef_to_enu
from coplane.gtime import GpsTime


def _truth_arrays(truth: Mapping[GpsTime, np.ndarray]) -> dict[GpsTime, np.ndarray]:
    return {t: np.asarray(p, dtype=float) for t, p in truth.items()}


NO_ERRORS = "no epoch with both a solution and a truth"


def _legend(ax: Axes, empty: str, fontsize: float | None = None) -> None:
    """The legend of what was drawn; on a figure with nothing drawn, `empty` says why (a truth of
    another day, a run that solved nothing) instead of matplotlib warning about the legend."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=fontsize)
    else:
        ax.text(0.5, 0.5, empty, ha="center", va="center", transform=ax.transAxes)


def plot_cdfs(
    runs: Sequence[MethodRun], truth: Mapping[GpsTime, np.ndarray], vehicle: str, out_dir: Path
) -> list[Path]:
    """Figs. 9-10 / 14-15: CDFs of horizontal and vertical errors per method for one vehicle."""
    paths = []
    tr = _truth_arrays(truth)
    for comp, name in (("h", "horizontal"), ("v", "vertical")):
        fig, ax = plt.subplots(figsize=(6, 4))
        for run in runs:
            _, e = enu_errors(run.positions.get(vehicle, {}), tr)
            if len(e) == 0:
                continue
            err = np.hypot(e[:, 0], e[:, 1]) if comp == "h" else np.abs(e[:, 2])
            x = np.sort(err)
            ax.plot(x, np.arange(1, len(x) + 1) / len(x), label=run.label)
        ax.set_xlabel(f"{name} error (m)")
        ax.set_ylabel("CDF")
        ax.set_title(f"{name.capitalize()} error CDF, vehicle {vehicle}")
        ax.grid(True, alpha=0.3)
        _legend(ax, NO_ERRORS, fontsize=8)
        p = out_dir / f"cdf_{comp}_{vehicle}.png"
        fig.tight_layout()
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths


def plot_error_vs_time(
    runs: Sequence[MethodRun], truth: Mapping[GpsTime, np.ndarray], vehicle: str, out_dir: Path
) -> Path:
    """Fig. 13: horizontal error over time, with the epochs that had inter-vehicle ranging marked."""
    fig, ax = plt.subplots(figsize=(9, 4))
    tr = _truth_arrays(truth)
    for run in runs:
        times, e = enu_errors(run.positions.get(vehicle, {}), tr)
        if not times:
            continue
        ax.plot([t.tow for t in times], np.hypot(e[:, 0], e[:, 1]), lw=1, label=run.label)
        rng = run.ranges_used.get(vehicle, {})
        if rng and any(rng.values()):
            ok = [t.tow for t in times if rng.get(t, 0) > 0]
            ax.plot(
                ok, np.full(len(ok), -0.3), "|", ms=4, alpha=0.5, label=f"ranging available ({run.label})"
            )
    ax.set_xlabel("GPS time of week (s)")
    ax.set_ylabel("horizontal error (m)")
    ax.set_title(f"Horizontal error vs time, vehicle {vehicle}")
    ax.grid(True, alpha=0.3)
    _legend(ax, NO_ERRORS, fontsize=7)
    p = out_dir / f"error_time_{vehicle}.png"
    fig.tight_layout()
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


def plot_rmse_vs_interruption(
    stats: Mapping[str, Mapping[float, AccuracyStats]], vehicle: str, out_dir: Path
) -> Path:
    """Figs. 11-12: horizontal and vertical RMSE against the ranging interruption rate."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for method, per_rate in stats.items():
        rates = sorted(per_rate)
        axes[0].plot([100 * r for r in rates], [per_rate[r].h_rmse_m for r in rates], "o-", label=method)
        axes[1].plot([100 * r for r in rates], [per_rate[r].v_rmse_m for r in rates], "o-", label=method)
    for ax, what in zip(axes, ("horizontal", "vertical"), strict=True):
        ax.set_xlabel("ranging interruption rate (%)")
        ax.set_ylabel(f"{what} RMSE (m)")
        ax.grid(True, alpha=0.3)
        _legend(ax, NO_ERRORS)
    fig.suptitle(f"RMSE vs ranging interruption, vehicle {vehicle}")
    p = out_dir / f"rmse_vs_interruption_{vehicle}.png"
    fig.tight_layout()
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


def plot_plane_map(
    run: MethodRun, truth_by_vehicle: Mapping[str, Mapping[GpsTime, np.ndarray]], out_dir: Path
) -> Path:
    """Fig. 16: where planes passed detection, passed after FE, or were unavailable."""
    colors = {"available": "tab:blue", "available-after-fe": "tab:red", "unavailable": "black"}
    fig, ax = plt.subplots(figsize=(7, 6))
    ref = None
    for vid, planes in sorted(run.planes.items()):
        pos = run.positions.get(vid, {})
        track = truth_by_vehicle.get(vid) or pos
        for status, col in colors.items():
            pts = [np.asarray(track[t]) for t, p in planes.items() if p.status == status and t in track]
            if not pts:
                continue
            arr = np.array(pts)
            if ref is None:
                ref = arr[0]
            enu = ecef_to_enu(arr, ref)
            ax.scatter(
                enu[:, 0],
                enu[:, 1],
                s=8,
                facecolors="none",
                edgecolors=col,
                label=f"{status}" if vid == sorted(run.planes)[0] else None,
            )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title(f"Plane availability along the route ({run.label})")
    _legend(ax, "no plane at an epoch with a position", fontsize=8)
    ax.grid(True, alpha=0.3)
    p = out_dir / "plane_map.png"
    fig.tight_layout()
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


def plot_map_tiles(features: dict[str, Any], out_path: Path, title: str = "Road-surface map") -> Path:
    """The map's tiles (a GeoJSON FeatureCollection from `roadmap.tiles_geojson`) coloured by the
    1-sigma of their road height, so a user sees where the map is sharp and where it is thin."""
    from matplotlib.collections import PolyCollection

    polys, sigmas = [], []
    for f in features.get("features", []):
        ring = f["geometry"]["coordinates"][0]
        s = f["properties"].get("sigma_m")
        if s is None:
            continue
        polys.append([(float(x), float(y)) for x, y in ring])
        sigmas.append(float(s))
    fig, ax = plt.subplots(figsize=(8, 6))
    if polys:
        lat0 = float(np.mean([p[0][1] for p in polys]))
        ax.set_aspect(1.0 / math.cos(math.radians(lat0)))  # metres look square
        coll = PolyCollection(polys, array=np.array(sigmas), cmap="viridis_r", edgecolors="none")
        coll.set_clim(0.0, max(0.05, float(np.percentile(sigmas, 95))))
        ax.add_collection(coll)
        ax.autoscale_view()
        fig.colorbar(coll, ax=ax, label="road height 1-sigma (m)")
    ax.set_xlabel("longitude (deg)")
    ax.set_ylabel("latitude (deg)")
    ax.set_title(f"{title}: {len(polys)} tiles")
    ax.ticklabel_format(useOffset=False)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
    return out_path
