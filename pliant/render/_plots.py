"""Matplotlib figures for studies (energy drift, phase portraits, convergence orders).

Figures are built with the object-oriented API on an Agg canvas (``matplotlib.figure.Figure``
+ ``FigureCanvasAgg``), never through pyplot: no backend switch, no global figure registry,
safe headless and inside notebooks.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["plot_series", "plot_phase_portrait", "plot_error_vs_dt", "fit_order"]


def _figure(figsize: tuple[float, float] = (6.4, 4.2)) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Any, path: str | os.PathLike, dpi: int) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path


def plot_series(
    path: str | os.PathLike,
    t: Sequence[float] | np.ndarray,
    series: Mapping[str, Sequence[float] | np.ndarray],
    ylabel: str,
    title: str = "",
    logy: bool = False,
    *,
    xlabel: str = "time [s]",
    dpi: int = 120,
) -> Path:
    """Line plot of several time series sharing one time axis (e.g. energies vs time).

    Args:
        path: Output image (format from the extension: .png, .pdf, .svg, ...).
        t: Times [T] (or any shared x values).
        series: Label -> values [T].
        ylabel: y-axis label (include units).
        title: Figure title.
        logy: Logarithmic y axis (non-positive values are not drawn).
        xlabel: x-axis label.
        dpi: Raster resolution.

    Returns:
        The output path.
    """
    t = np.asarray(t, dtype=np.float64)
    fig = _figure()
    ax = fig.add_subplot()
    for label, y in series.items():
        y = np.asarray(y, dtype=np.float64)
        if y.shape != t.shape:
            raise ValueError(f"series {label!r} has shape {y.shape}, expected {t.shape}")
        if logy:
            y = np.where(y > 0.0, y, np.nan)
        ax.plot(t, y, label=label, lw=1.5)
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    if series:
        ax.legend()
    return _save(fig, path, dpi)


def plot_phase_portrait(
    path: str | os.PathLike,
    curves: Mapping[str, tuple[np.ndarray, np.ndarray]],
    exact: tuple[np.ndarray, np.ndarray] | None = None,
    *,
    title: str = "phase portrait",
    xlabel: str = "x [m]",
    ylabel: str = "v [m/s]",
    dpi: int = 120,
) -> Path:
    """Phase portrait (position vs velocity) of several integrators, optionally with the exact orbit.

    Args:
        path: Output image.
        curves: Label -> (x [T], v [T]).
        exact: Reference (x, v) drawn as a dashed black line.
        title: Figure title.
        xlabel: Horizontal-axis label.
        ylabel: Vertical-axis label.
        dpi: Raster resolution.

    Returns:
        The output path.
    """
    fig = _figure((5.6, 5.0))
    ax = fig.add_subplot()
    if exact is not None:
        ax.plot(np.asarray(exact[0]), np.asarray(exact[1]), "k--", lw=1.2, label="exact")
    for label, (x, v) in curves.items():
        ax.plot(np.asarray(x), np.asarray(v), lw=1.2, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    if curves or exact is not None:
        ax.legend()
    return _save(fig, path, dpi)


def fit_order(dts: Sequence[float] | np.ndarray, errors: Sequence[float] | np.ndarray) -> float:
    """Least-squares slope of log(error) vs log(dt), i.e. the observed convergence order.

    Args:
        dts: Step sizes [K] in seconds.
        errors: Errors [K]; non-positive or non-finite entries are ignored.

    Returns:
        The slope, or NaN with fewer than two usable points.
    """
    dts = np.asarray(dts, dtype=np.float64)
    err = np.asarray(errors, dtype=np.float64)
    ok = np.isfinite(dts) & np.isfinite(err) & (dts > 0.0) & (err > 0.0)
    if np.count_nonzero(ok) < 2 or np.ptp(np.log(dts[ok])) == 0.0:
        return float("nan")
    return float(np.polyfit(np.log(dts[ok]), np.log(err[ok]), 1)[0])


def plot_error_vs_dt(
    path: str | os.PathLike,
    dts: Sequence[float] | np.ndarray,
    errors: Mapping[str, Sequence[float] | np.ndarray],
    orders: Mapping[str, float] | None = None,
    *,
    title: str = "convergence",
    xlabel: str = "time step dt [s]",
    ylabel: str = "error",
    dpi: int = 120,
) -> Path:
    """Log-log error vs time step, with each method's fitted slope in the legend.

    Args:
        path: Output image.
        dts: Step sizes [K] in seconds, shared by all methods.
        errors: Label -> errors [K].
        orders: Optional label -> expected order p; draws a dotted ``dt^p`` reference line
            through that method's finest-step point.
        title: Figure title.
        xlabel: Horizontal-axis label.
        ylabel: Vertical-axis label.
        dpi: Raster resolution.

    Returns:
        The output path.
    """
    dts = np.asarray(dts, dtype=np.float64)
    fig = _figure()
    ax = fig.add_subplot()
    for label, e in errors.items():
        e = np.asarray(e, dtype=np.float64)
        if e.shape != dts.shape:
            raise ValueError(f"errors {label!r} has shape {e.shape}, expected {dts.shape}")
        slope = fit_order(dts, e)
        ok = (e > 0.0) & np.isfinite(e)
        (line,) = ax.plot(dts[ok], e[ok], "o-", lw=1.5, ms=4, label=f"{label} (slope {slope:.2f})")
        if orders is not None and label in orders and ok.any():
            p = float(orders[label])
            k = np.flatnonzero(ok)[np.argmin(dts[ok])]
            ref = e[k] * (dts[ok] / dts[k]) ** p
            ax.plot(dts[ok], ref, ":", color=line.get_color(), lw=1.2, label=f"O(dt^{p:g})")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    if errors:
        ax.legend(fontsize="small")
    return _save(fig, path, dpi)
