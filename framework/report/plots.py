"""Matplotlib figures of a report, as PNG bytes.

The figures follow [P10]: per-frame error curves (fig. 10), error against
the number of influences k (fig. 12) and histograms of the number of
non-zero weights per vertex before and after reduction (fig. 8). Figures are
drawn on the Agg canvas directly (no pyplot, no global backend change), so
they work headless and never touch a user's matplotlib state.
"""

from __future__ import annotations

import io
import math

import numpy as np

#: Colours of successive evaluations (matplotlib's tab10).
PALETTE = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
           "#bcbd22", "#17becf"]
DPI = 100


def _figure(width_in: float, height_in: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def color(i: int) -> str:
    return PALETTE[i % len(PALETTE)]


def error_curves(rows) -> bytes:
    """Per-test-frame errors of every evaluation ([P10] fig. 10), one panel per measured error.

    Parameters
    ----------
    rows : list of rigslim.report.EvaluationRow
        Each with ``label``, ``frames``, ``position_per_frame`` (% of the
        bounding-box diagonal), ``normal_per_frame`` (radians; drawn in
        degrees) and ``metro_per_frame`` (% of the diagonal); a panel is
        drawn for each that any row has.
    """
    panels = [(attr, label, scale) for attr, label, scale in (
        ("position_per_frame", "position RMS (% of diagonal)", 1.0),
        ("normal_per_frame", "normal RMS (degrees)", 180.0 / math.pi),
        ("metro_per_frame", "Metro RMS (% of diagonal)", 1.0))
        if any(getattr(r, attr, None) is not None for r in rows)]
    fig = _figure(8.0, 1.0 + 2.1 * max(len(panels), 1))
    axes = fig.subplots(max(len(panels), 1), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (attr, label, scale) in zip(axes, panels, strict=False):
        for i, r in enumerate(rows):
            per = getattr(r, attr, None)
            if per is not None and len(per) == len(r.frames):
                ax.plot(r.frames, np.asarray(per) * scale, color=color(i), lw=1.4, marker=".", ms=3, label=r.label)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.set_ylim(bottom=0)
    if not panels:
        axes[0].text(0.5, 0.5, "no per-frame errors in these documents", ha="center", va="center",
                     transform=axes[0].transAxes)
    axes[-1].set_xlabel("test frame")
    axes[0].set_title("Error per test frame")
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=8, loc="upper left", ncols=min(len(rows), 3))
    return _png(fig)


def error_vs_k(rows) -> bytes:
    """Mean (solid) and maximum (dashed) error against k, one line per method ([P10] fig. 12)."""
    fig = _figure(8.0, 3.4)
    ax_p, ax_n = fig.subplots(1, 2)
    methods: dict[str, list] = {}
    for r in rows:
        if r.k is not None:
            methods.setdefault(r.method, []).append(r)
    for i, (method, group) in enumerate(methods.items()):
        group = sorted(group, key=lambda r: r.k)
        ks = [r.k for r in group]
        for ax, mean, peak, scale in ((ax_p, "position_mean", "position_max", 1.0),
                                      (ax_n, "normal_mean", "normal_max", 180 / math.pi)):
            pts = [(k, getattr(r, mean), getattr(r, peak)) for k, r in zip(ks, group, strict=False)
                   if getattr(r, mean) is not None]
            if not pts:
                continue
            k_, m_, x_ = zip(*pts, strict=False)
            ax.plot(k_, np.array(m_) * scale, color=color(i), marker="o", label=f"{method} mean")
            ax.plot(k_, np.array(x_) * scale, color=color(i), marker="^", ls="--", alpha=0.7, label=f"{method} max")
    ax_p.set_ylabel("position RMS (% of diagonal)")
    ax_n.set_ylabel("normal RMS (degrees)")
    for ax in (ax_p, ax_n):
        ax.set_xlabel("k (influences per vertex)")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.xaxis.get_major_locator().set_params(integer=True)
    ax_p.legend(fontsize=8)
    fig.suptitle("Error against k")
    return _png(fig)


def influence_histograms(rows) -> bytes:
    """Vertices per number of non-zero weights, input and reduced ([P10] fig. 8).

    ``rows`` need ``histogram_input`` and ``histogram_reduced`` (lists whose
    entry c is the number of vertices with c non-zero weights) or None.
    """
    fig = _figure(8.0, 3.4)
    ax_in, ax_out = fig.subplots(1, 2, sharey=True)
    inputs: dict[tuple, list] = {}
    for r in rows:
        if r.histogram_input is not None:
            inputs.setdefault(tuple(r.histogram_input), []).append(r.label)
    for j, (hist, labels) in enumerate(inputs.items()):
        width = 0.8 / len(inputs)
        x = np.arange(len(hist)) - 0.4 + width * (j + 0.5)
        name = "input" if len(inputs) == 1 else f"input of {labels[0]}"
        ax_in.bar(x, hist, width=width, color="#7f7f7f" if len(inputs) == 1 else color(j), label=name)
    with_hist = [r for r in rows if r.histogram_reduced is not None]
    for j, r in enumerate(with_hist):
        width = 0.8 / len(with_hist)
        hist = r.histogram_reduced
        x = np.arange(len(hist)) - 0.4 + width * (j + 0.5)
        ax_out.bar(x, hist, width=width, color=color(rows.index(r)), label=r.label)
    ax_in.set_title("before: input weights")
    ax_out.set_title("after: reduced weights")
    ax_in.set_ylabel("vertices")
    for ax in (ax_in, ax_out):
        ax.set_xlabel("non-zero weights per vertex")
        ax.grid(alpha=0.3, axis="y")
        ax.xaxis.get_major_locator().set_params(integer=True)
        if ax.has_data():
            ax.legend(fontsize=8)
    return _png(fig)


def colorbar(vmax: float, cmap: str, label: str = "normal deviation (degrees)", clipped: bool = False) -> bytes:
    """A horizontal colour scale from 0 to ``vmax`` (in the unit ``label`` names) for heat-map renders.

    ``clipped`` draws the top as a pointed end: values above ``vmax`` exist and are drawn in its colour.
    """
    from matplotlib.colorbar import ColorbarBase
    from matplotlib.colors import Normalize

    fig = _figure(4.8, 0.8)
    ax = fig.add_subplot(1, 1, 1)
    ColorbarBase(ax, cmap=cmap, norm=Normalize(0, vmax), orientation="horizontal",
                 extend="max" if clipped else "neither")
    ax.set_xlabel(label, fontsize=8)
    ax.tick_params(labelsize=8)
    return _png(fig)


#: Data spanning more than this ratio (largest / smallest positive value) get logarithmic histogram bins.
LOG_BINS_SPAN = 100.0


def histogram_bins(values, count: int) -> tuple[np.ndarray, bool]:
    """Bin edges for a histogram of ``values``, and whether they are logarithmic.

    Linear bins put almost every value into the first bin when the values
    span decades (one asset at 1e-10 %, another at 5 %), so values whose
    positive part spans more than :data:`LOG_BINS_SPAN` (two decades),
    ``max(x) / min(x > 0) > 100``, get ``count`` bins of equal width in
    ``log10 x`` from ``min(x > 0)`` to ``max(x)``; zeros and negative values
    then fall outside (the caller says how many). Otherwise ``count``
    linear bins from ``min(x)`` to ``max(x)``.
    """
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    positive = x[x > 0]
    if len(positive) >= 2 and positive.max() / positive.min() > LOG_BINS_SPAN:
        return np.geomspace(positive.min(), positive.max(), count + 1), True
    lo, hi = (float(x.min()), float(x.max())) if len(x) else (0.0, 1.0)
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    return np.linspace(lo, hi, count + 1), False
