"""The report's figures as PNG bytes (matplotlib, Agg), to be inlined in the page.

* :func:`deviations_png` - the measured deviations against R_a[k]: the figure of ``reachset
  check --plot`` (:func:`reachset_ros.plots.plot_deviations`), drawn by that function.
* :func:`set_use_png` - set use over time, one panel per bag: ``|deviation| / bound`` per tick
  on a linear axis, the boundary 1.0 as a line, the violating ticks (above 1) marked, the
  safe stops and fault onsets as vertical lines (seconds from the bag's start).
"""
from __future__ import annotations

import io
import tempfile
from pathlib import Path

import numpy as np

from ..plots import plot_deviations

__all__ = ["deviations_png", "set_use_png", "peaks"]

#: most points per line: longer series are reduced to the largest value per bin (peaks kept)
MOST_POINTS = 4000


def deviations_png(name, model, thm, devs):
    """PNG bytes of ``reachset check --plot``'s figure of joint ``name``."""
    with tempfile.TemporaryDirectory(prefix="reachset_report_") as d:
        return Path(plot_deviations(d, name, model, thm, devs)).read_bytes()


def peaks(t, v, most=MOST_POINTS):
    """``(t, v)`` reduced to at most ``most`` points, each the largest ``v`` of its bin (NaN
    ignored), so that a short excursion above 1 stays visible."""
    n = len(v)
    if n <= most:
        return t, v
    edges = np.linspace(0, n, most + 1).astype(int)
    tt, vv = np.empty(most), np.full(most, np.nan)
    for i in range(most):
        a, b = edges[i], edges[i + 1]
        seg = v[a:b]
        ok = ~np.isnan(seg)
        if ok.any():
            j = a + int(np.nanargmax(seg))
            tt[i], vv[i] = t[j], v[j]
        else:
            tt[i] = t[a]
    return tt, vv


def _panel(ax, name, run):
    j = run.joints[name]
    t, v = peaks(j.t_s, j.use)
    ax.plot(t, v, lw=0.7, color="tab:blue", label="set use |y_a| / bound (largest over the tick's checks)")
    ax.axhline(1.0, color="k", lw=1.2, label="boundary of R_a (1.0)")
    finite = j.use[np.isfinite(j.use)]
    top = max(1.2, 1.1 * float(finite.max())) if len(finite) else 1.2
    if j.violations:
        vt = j.violation_times()
        vu = j.use[j.violating]
        # a NaN deviation's use is infinite (fail closed): drawn at the top of the axis
        ax.plot(vt, np.where(np.isfinite(vu), vu, top), "x", color="tab:red", ms=4,
                label=f"violations ({j.violations} ticks, first at {vt[0]:.3f} s)")
    for kind, col in (("stop", "tab:red"), ("reset", "tab:green"), ("fault onset", "0.3")):
        ts = [ev.t_s for ev in run.events if ev.kind == kind]
        if ts:        # one line per event, one legend entry per kind (a campaign's bag has hundreds)
            ax.vlines(ts, 0.0, 1.0, transform=ax.get_xaxis_transform(), colors=col, linestyles="--", lw=1,
                      label=f"{kind} at {ts[0]:.3f} s" if len(ts) == 1 else f"{kind} ({len(ts)}, first at {ts[0]:.3f} s)")
    ax.set_ylim(0.0, top)
    ax.set_xlabel("time from the bag's start [s]")
    ax.set_ylabel("set use")
    ax.set_title(f"{name}: {Path(run.path).name}", fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    ax.grid(alpha=0.3)


def set_use_png(name, runs):
    """PNG bytes of joint ``name``'s set use over time, one panel per bag that has the joint."""
    from ..plots import _plt    # the plots' one matplotlib set-up (Agg)
    plt = _plt()
    runs = [r for r in runs if name in r.joints]
    fig, axes = plt.subplots(len(runs), 1, figsize=(8, 2.8 * len(runs)), squeeze=False)
    for ax, run in zip(axes[:, 0], runs):
        _panel(ax, name, run)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()
