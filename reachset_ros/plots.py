"""PNG figures of the synthesis results, in the style of the paper's Figs. 6-9 (matplotlib, Agg).

* :func:`plot_tracking_error` - ``R_e`` as a box in the (position error, velocity error)
  plane with the measured tracking errors ``[q_hat - q_d, qd_hat - qd_d]`` of the bag
  (needs ``/observer/estimate`` and ``/reference``); the separate approach's box and the
  LQG boxes when given (paper Figs. 6, 7, 9).
* :func:`plot_input` - the measured plant inputs ``u_p`` over time with ``R_u`` and ``U_p``
  (paper Fig. 6, right).
* :func:`plot_conformance` - Theorem 1: the extremes of the deviations ``y_a[k]`` over all
  test cases against the bounds of ``R_a[k]`` (available for every bag; the plot to look at
  when the bag has no estimates/references).
* :func:`plot_status_set_use` - the monitor's set use over time from ``/conformance/status``
  (:func:`status_set_use`), on a linear axis with the boundary 1.0 drawn and the violations
  (use > 1) marked (issue 36.3).

Every function writes one PNG and returns its path. No ROS import.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .bags.messages import DIAGNOSTICS_TOPIC, ESTIMATE_TOPIC, REFERENCE_TOPIC, STATUS_TOPIC, header_stamp_ns
from .bags.references import read_references
from .bags import read_messages
from .conformance import model as mdl
from .conformance.theorem1 import xi_of
from .synthesis.config import components_from_gains
from .synthesis.reference_error import reference_error

__all__ = ["plot_tracking_error", "plot_input", "plot_conformance", "plot_joint", "tracking_errors",
           "status_set_use", "set_use_figure", "plot_status_set_use"]


def _plt():
    import matplotlib  # heavy optional dependency: only the plots need it
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt  # heavy optional dependency (after choosing the Agg backend)
    return plt


def _save(plt, fig, path):
    """Lay out, write the PNG and free the figure."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _box(ax, center, radius, **kw):
    from matplotlib.patches import Rectangle  # heavy optional dependency: only the plots need it
    c, r = np.asarray(center, float), np.asarray(radius, float)
    ax.add_patch(Rectangle((c[0] - r[0], c[1] - r[1]), 2 * r[0], 2 * r[1], fill=False, **kw))


def _thin(n, most=20000):
    return np.arange(n) if n <= most else np.linspace(0, n - 1, most).astype(int)


def tracking_errors(estimates, references):
    """Measured tracking errors of one joint, paired by stamp.

    Parameters
    ----------
    estimates : (stamps, values (T, >= 2)) with q_hat, qd_hat columns
    references : list of :class:`reachset_ros.bags.references.Reference`

    Returns
    -------
    ndarray (N, 2) of [q_hat - q_d, qd_hat - qd_d] at the common stamps
    """
    if estimates is None or not references:
        return np.zeros((0, 2))
    st, v = estimates
    rs = np.concatenate([r.stamps for r in references])
    rq = np.concatenate([r.q for r in references])
    rqd = np.concatenate([r.qd for r in references])
    common, ie, ir = np.intersect1d(st, rs, return_indices=True)
    return np.column_stack([v[ie, 0] - rq[ir], v[ie, 1] - rqd[ir]])


def plot_tracking_error(path, result, errors=None, separate=None, lqg=None, title=None):
    """R_e (interval hull) as a box with measured tracking errors; separate/LQG boxes overlaid.

    Parameters
    ----------
    path : path of the PNG
    result : :class:`reachset_ros.synthesis.JointResult`
    errors : ndarray (N, 2), optional
        Measured ``[q_hat - q_d, qd_hat - qd_d]``.
    separate : JointResult, optional
    lqg : list of dict, optional
        Rows of :func:`reachset_ros.synthesis.lqg_baseline` (boxes need ``re_radius``).
    """
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    if errors is not None and len(errors):
        i = _thin(len(errors))
        ax.plot(errors[i, 0], errors[i, 1], ".", ms=1.5, color="0.5", alpha=0.5, label="measured tracking error (recording's gains)")
    _box(ax, result.re_center, result.re_radius, ec="tab:blue", lw=2,
         label=f"R_e {result.mode} (||R_e|| = {result.re_norm:.3g})")
    rads = [np.asarray(result.re_radius)]
    if separate is not None:
        _box(ax, separate.re_center, separate.re_radius, ec="tab:red", lw=1.5, ls="--",
             label=f"R_e separate (||R_e|| = {separate.re_norm:.3g})")
        rads.append(np.asarray(separate.re_radius))
    for row in lqg or []:
        if row.get("re_radius"):
            _box(ax, result.re_center, row["re_radius"], ec="tab:green", lw=1, ls=":",
                 label=f"LQG r = {row['r']:g} (||R_e|| = {row['re_norm']:.3g})")
            rads.append(np.asarray(row["re_radius"]))
    r = np.max(rads, axis=0) * 1.15 + np.abs(np.asarray(result.re_center))
    ax.set_xlim(-r[0], r[0])
    ax.set_ylim(-r[1], r[1])
    ax.set_xlabel("position error  q_hat - q_d  [rad]")
    ax.set_ylabel("velocity error  qd_hat - qd_d  [rad/s]")
    ax.set_title(title or f"{result.name}: reachable tracking error")
    ax.legend(loc="upper right", fontsize=7)
    ax.grid(alpha=0.3)
    _save(plt, fig, path)
    return Path(path)


def plot_input(path, result, u=None, dt=0.004, separate=None, title=None):
    """Measured plant input over time against R_u and U_p."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    if u is not None and len(u):
        u = np.asarray(u, float).ravel()
        i = _thin(len(u))
        ax.plot(i * dt, u[i], lw=0.5, color="0.4", label="measured u_p")
    T = (len(u) if u is not None and len(u) else 1) * dt
    ax.axhspan(result.ru[0], result.ru[1], color="tab:blue", alpha=0.15,
               label=f"R_u {result.mode} [{result.ru[0]:.3g}, {result.ru[1]:.3g}]")
    if separate is not None:
        for v in separate.ru:
            ax.axhline(v, color="tab:red", ls="--", lw=1)
        ax.plot([], [], color="tab:red", ls="--", label=f"R_u separate [{separate.ru[0]:.3g}, {separate.ru[1]:.3g}]")
    for v in (-result.u_max, result.u_max):
        ax.axhline(v, color="k", lw=1.5)
    ax.plot([], [], color="k", label=f"U_p = [-{result.u_max:g}, {result.u_max:g}]")
    ax.set_xlim(0, T)
    lim = 1.1 * max(result.u_max, abs(result.ru[0]), abs(result.ru[1]))
    ax.set_ylim(-lim, lim)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("u_p [rad/s^2]")
    ax.set_title(title or f"{result.name}: reachable input")
    ax.legend(loc="upper right", fontsize=7)
    ax.grid(alpha=0.3)
    _save(plt, fig, path)
    return Path(path)


def plot_conformance(path, problem, result, separate=None, title=None):
    """Theorem 1 per k: max/min of the deviations y_a[k] over all test cases vs. R_a[k]."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    K = len(problem.devs.maxp)
    k = np.arange(K)
    up = np.array([problem.devs.maxp[i][0] for i in range(K)])
    lo = np.array([-problem.devs.maxm[i][0] for i in range(K)])
    ax.fill_between(k, lo, up, color="0.6", alpha=0.6, label="measured y_a (all test cases)")
    for res, col, ls, lab in ((result, "tab:blue", "-", result.mode), (separate, "tab:red", "--", "separate")):
        if res is None:
            continue
        xi = xi_of(res.c_w, res.c_v, res.alpha_w, res.alpha_v)
        offs = problem.thm.offsets(xi)
        dp = np.array([o[0][0] for o in offs])
        dm = np.array([o[1][0] for o in offs])
        ax.plot(k, dp, color=col, ls=ls, label=f"R_a bounds ({lab})")
        ax.plot(k, -dm, color=col, ls=ls)
    ax.set_xlabel("k (ticks after the test case's start)")
    ax.set_ylabel("y_a [rad]")
    ax.set_title(title or f"{problem.name}: reachset conformance (Theorem 1)")
    ax.legend(loc="upper left", fontsize=7)
    ax.grid(alpha=0.3)
    _save(plt, fig, path)
    return Path(path)


def plot_joint(directory, problem, result, estimates=None):
    """All figures of one joint into ``directory``; returns the list of written paths.

    ``estimates``: ``(stamps, values)`` of ``/observer/estimate`` for this joint, or None.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    sep = result.separate
    lqg = result.extra.get("lqg")
    errs = tracking_errors(estimates, problem.references)
    out = [plot_tracking_error(d / f"{result.name}_re.png", result, errs, sep, lqg),
           plot_input(d / f"{result.name}_ru.png", result, problem.u[:, 0], problem.plant.dt, sep),
           plot_conformance(d / f"{result.name}_conformance.png", problem, result, sep)]
    return out


def _read_topics(bag, topics):
    """{topic: {stamp: msg}} of a bag (small demo bags only)."""
    out = {t: {} for t in topics}
    for topic, _t, m in read_messages([bag], topics):
        out[topic][header_stamp_ns(m)] = m
    return out


def run_tracking_set(model, joint, references, inflation):
    """The tracking-error box that the monitor's model guarantees for the references of a run.

    Paper Appendix B (method 3) applied to the references actually run, not to the training
    ones: ``R*_e = Y_e,ref (+) R_e``, where ``Y_e,ref`` is the nominal loop's reference error
    for ``references`` (:func:`reachset_ros.synthesis.reference_error.reference_error`, exact on every
    tick) and ``R_e`` the disturbance part of the synthesis, scaled by ``1 + inflation`` (with zero
    centers R_e is linear in alpha, and the monitor accepts data conformant to the inflated
    sets). Returns (center, radius) of the interval hull (position, velocity), or None when
    the model has no gains for the joint.
    """
    js = model.joints.get(joint)
    g = dict(js.gains) if js is not None else {}
    if not g or "re_radius" not in g:
        return None
    ref_old = (js.extra or {}).get("reference_error", {}).get("y_e_ref")
    r_total = np.asarray(g["re_radius"][:2], float)
    half_old = (np.array([b - a for a, b in ref_old[:2]]) / 2.0) if ref_old else np.zeros(2)
    r_dist = np.maximum(r_total - half_old, 0.0)
    obs, ctrl = components_from_gains(g, model.plant.dt)
    ref = reference_error(model.plant, obs, ctrl, references)
    lo, hi = np.asarray(ref.e_lo[:2], float), np.asarray(ref.e_hi[:2], float)
    return 0.5 * (lo + hi), (1.0 + inflation) * r_dist + 0.5 * (hi - lo)


def controller_transients(diagnostics):
    """The transient windows the controller reported: ``{joint: [(start_ns, end_ns), ...]}``.

    ``diagnostics``: ``DiagnosticArray`` messages (``/diagnostics``). controller_node reports,
    after its start, each gain change and each end of braking, the stamps from which
    (``transient_start_ns``) and until which (``transient_end_ns/JOINT``, from the closed
    loop's settling time, :func:`reachset_ros.systems.closedloop.settling_ticks`) the
    tracking error is not claimed to lie in ``R*_e``. Windows of the same start are merged.
    """
    out = {}
    for arr in diagnostics:
        for st in arr.status:
            if st.name != "reachset_ros: controller":
                continue
            kv = {v.key: v.value for v in st.values}
            if "transient_start_ns" not in kv:
                continue
            start = int(kv["transient_start_ns"])
            for k, v in kv.items():
                if k.startswith("transient_end_ns/"):
                    out.setdefault(k.split("/", 1)[1], set()).add((start, int(v)))
    return {j: sorted(w) for j, w in out.items()}


def demo_tracking(data, syn, until, model=None, references=None, inflation=0.0, transients=None):
    """Measured tracking errors of the demo's monitored run (before ``until``) against R_e.

    The error is the observer's estimate minus the reference (position, velocity), as the
    controller sees it. Two boxes: the synthesis' ``R*_e`` (training references, the sets as
    identified; centered at zero as reported) and, when ``model`` and ``references`` are
    given, :func:`run_tracking_set` (the references of this run, the sets inflated as the monitor's).
    ``R_e`` holds from zero initial error, so ticks inside a transient window after a start,
    gain change or braking (``transients``: :func:`controller_transients`) are not judged:
    the shares count only the ticks outside them. Returns {joint: {"max_abs_error",
    "re_radius", "share_inside", "ticks" (judged), "ticks_in_transient" (excluded),
    "transient_s" (the longest window), and with a model "run_center", "run_radius",
    "share_inside_run"}} and the per-joint error arrays (all ticks).
    """
    est, ref = data[ESTIMATE_TOPIC], data[REFERENCE_TOPIC]
    stamps = sorted(s for s in est if s in ref and s < until)
    stats, errors = {}, {}
    if not stamps:
        return stats, errors
    t = np.array(stamps, dtype=np.int64)
    for name, j in syn.items():
        def idx(msg):
            return list(msg.name).index(name)
        e = np.array([[est[s].position[idx(est[s])] - ref[s].position[idx(ref[s])],
                       est[s].velocity[idx(est[s])] - ref[s].velocity[idx(ref[s])]] for s in stamps])
        windows = (transients or {}).get(name, [])
        judged = np.ones(len(t), dtype=bool)
        for lo, hi in windows:
            judged &= ~((t >= lo) & (t < hi))
        r = [float(x) for x in j["re_radius"][:2]]
        inside = (np.abs(e[:, 0]) <= r[0]) & (np.abs(e[:, 1]) <= r[1])
        n = int(judged.sum())
        st = {"max_abs_error": np.abs(e[judged]).max(axis=0).tolist() if n else [0.0, 0.0], "re_radius": r,
              "share_inside": float(inside[judged].mean()) if n else float("nan"), "ticks": n,
              "ticks_in_transient": int(len(t) - n),
              "transient_s": max(((hi - lo) * 1e-9 for lo, hi in windows), default=0.0)}
        if model is not None and references is not None and references.get(name):
            # the joint's own inflation in the monitor's model (issue 35.1); ``inflation``: a model without joints' own
            box = run_tracking_set(model, name, references[name],
                                   model.joint_inflation(name) if name in model.joints else inflation)
            if box is not None:
                c, rr = box
                inside_run = np.all(np.abs(e - c) <= rr, axis=1)
                st.update(run_center=c.tolist(), run_radius=rr.tolist(),
                          share_inside_run=float(inside_run[judged].mean()) if n else float("nan"))
        stats[name] = st
        errors[name] = e
    return stats, errors


def demo_plots(res, record, workdir):
    """Figures of ``reachset demo``: per joint the measured tracking errors of the monitored
    run (before the fault) against the guaranteed R_e, and the monitor's set use over time
    (:func:`plot_status_set_use`) with the fault and the safe stop marked. Returns the PNG paths and :func:`demo_tracking`'s
    statistics."""
    plt = _plt()
    outdir = Path(workdir) / "plots"
    outdir.mkdir(parents=True, exist_ok=True)
    data = _read_topics(record, [ESTIMATE_TOPIC, REFERENCE_TOPIC, STATUS_TOPIC])
    status = data[STATUS_TOPIC]
    fault = res.get("fault_injected_ns")
    stop = res.get("safe_stop_ns")
    until = min(x for x in (fault, stop, float("inf")) if x is not None)
    syn = (res.get("reidentify") or res.get("synthesis") or {}).get("joints", {})
    model, refs = None, None
    if res.get("monitor_model"):
        model = mdl.load(res["monitor_model"])
        refs = {n: [r.slice(0, int(np.searchsorted(r.stamps, until))) for r in rs
                    if len(r) and r.stamps[0] < until]
                for n, rs in read_references([record]).items()}
    # "margin": the deprecated name of "inflation" in results of older versions
    inflation = res.get("inflation", res.get("margin"))
    transients = controller_transients(m for _t, _lt, m in read_messages([record], [DIAGNOSTICS_TOPIC]))
    stats, errors = demo_tracking(data, syn, until, model, refs, float(inflation or 0.0), transients)
    paths = []
    names = list(errors)
    if names:
        fig, axes = plt.subplots(2, (len(names) + 1) // 2, figsize=(4 * ((len(names) + 1) // 2), 7))
        for ax, name in zip(np.ravel(axes), names):
            j, e, r = syn[name], errors[name], stats[name]["re_radius"]
            st = stats[name]
            _box(ax, [0.0, 0.0], r, edgecolor="tab:blue", linewidth=1, linestyle="--",
                 label="R*_e of the synthesis (training references)")
            ext = np.array(r)
            title = f"{name}: {st['share_inside']:.1%} in R*_e"
            if st.get("ticks_in_transient"):
                title += f" ({st['ticks_in_transient']} transient ticks not judged)"
            if "run_radius" in st:
                _box(ax, st["run_center"], st["run_radius"], edgecolor="tab:green", linewidth=2,
                     label="R*_e of this run (its references, the monitor's inflation)")
                ext = np.maximum(ext, np.abs(st["run_center"]) + np.array(st["run_radius"]))
                title += f", {st['share_inside_run']:.1%} in this run's"
            ax.plot(e[:, 0], e[:, 1], ".", ms=1, color="tab:red", label="measured (estimate - reference)")
            ax.set_title(title, fontsize=8)
            ax.set_xlabel("q error [rad]")
            ax.set_ylabel("qdot error [rad/s]")
            ext = np.maximum(ext, np.abs(e).max(axis=0))
            ax.set_xlim(-1.2 * ext[0], 1.2 * ext[0])
            ax.set_ylim(-1.2 * ext[1], 1.2 * ext[1])
        np.ravel(axes)[0].legend(fontsize=7, loc="upper right")
        p = outdir / "demo_tracking_error.png"
        _save(plt, fig, p)
        paths.append(str(p))
    if status:
        paths.append(str(plot_status_set_use(outdir / "demo_monitor_set_use.png", list(status.values()),
                                             {"fault": fault, "safe stop": stop})))
    return paths, stats


def status_set_use(msgs):
    """The set use of ``/conformance/status`` messages: ``(names, stamps_ns (T,), use (T, J))``.

    A message's ``set_use`` (the monitor's, issue 36.3: the largest ``|N y_a| / bound`` over the
    tick's checks, 1.0 on the boundary, above 1 a violation, NaN when nothing was checked); a
    message without it (a bag recorded before the field was added) gives
    ``deviation / (deviation + margin)`` of its tightest check (NaN where nothing was checked:
    a margin of +-1e300). The joints are those of the first message, in its order.
    """
    msgs = sorted(msgs, key=header_stamp_ns)
    names = list(msgs[0].name) if msgs else []
    stamps = np.array([header_stamp_ns(m) for m in msgs], dtype=np.int64)
    use = np.full((len(msgs), len(names)), np.nan)
    for i, m in enumerate(msgs):
        col = {n: j for j, n in enumerate(m.name)}
        given = np.asarray(getattr(m, "set_use", ()), dtype=float).ravel()
        if len(given) == len(m.name):
            row = given
        else:
            dev, margin = np.asarray(m.deviation, float), np.asarray(m.margin, float)
            bound = dev + margin
            with np.errstate(divide="ignore", invalid="ignore"):
                row = np.where((np.abs(margin) < 1e299) & (bound > 0), dev / np.where(bound > 0, bound, 1.0), np.nan)
        use[i] = [row[col[n]] if n in col else np.nan for n in names]
    return names, stamps, use


def set_use_figure(names, t, use, marks=None):
    """The figure of :func:`plot_status_set_use`: ``(fig, ax)``, one line per joint over ``t`` [s].

    Linear axis from 0; the boundary of the reachable sets (1.0) drawn, the region above it
    shaded, each tick with a use above 1 marked (a violation); an infinite use (a NaN
    deviation, fail closed) drawn at the top of the axis. ``marks``: ``{label: t}`` vertical lines.
    """
    plt = _plt()
    use = np.asarray(use, float)
    finite = use[np.isfinite(use)]
    top = max(1.1, 1.05 * float(finite.max())) if len(finite) else 1.1
    fig, ax = plt.subplots(figsize=(9, 4))
    for i, name in enumerate(names):
        u = np.where(np.isposinf(use[:, i]), top, use[:, i])
        (line,) = ax.plot(t, u, lw=0.8, label=name)
        over = u > 1.0
        if over.any():
            ax.plot(np.asarray(t)[over], u[over], "x", ms=4, color=line.get_color())
    ax.axhline(1.0, color="r", lw=1.2, label="boundary of the reachable set (1.0)")
    ax.axhspan(1.0, top, color="r", alpha=0.07, lw=0)
    for (lab, x), c in zip((marks or {}).items(), ("k", "m", "c", "y")):
        if x is not None:
            ax.axvline(x, color=c, ls="--", label=lab)
    ax.set_ylim(0.0, top)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("set use |N y_a| / bound (> 1: violation)")
    ax.legend(fontsize=7, ncol=4, loc="upper left")
    return fig, ax


def plot_status_set_use(path, msgs, marks=None):
    """The monitor's set use over time (:func:`status_set_use` of the ``/conformance/status``
    messages ``msgs``, :func:`set_use_figure`) as a PNG at ``path``; ``marks``: ``{label:
    stamp_ns}`` (e.g. the fault and the safe stop). Returns the path."""
    plt = _plt()
    names, stamps, use = status_set_use(msgs)
    t0 = int(stamps[0]) if len(stamps) else 0
    fig, _ax = set_use_figure(names, (stamps - t0) * 1e-9, use,
                              {k: None if v is None else (v - t0) * 1e-9 for k, v in (marks or {}).items()})
    _save(plt, fig, path)
    return Path(path)


def plot_deviations(directory, name, model, thm, devs):
    """Theorem 1 as a picture: per k the largest and smallest measured deviation y_a over
    all test cases of a recording against the reachable set R_a[k] of the model (one-dimensional
    outputs). Returns the PNG path."""
    plt = _plt()
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    offs = thm.offsets(model.checked_xi(name))
    k = np.arange(len(offs))
    hi = np.array([o[0][0] for o in offs])
    lo = -np.array([o[1][0] for o in offs])
    ymax = np.array([m[0] for m in devs.maxp])
    ymin = -np.array([m[0] for m in devs.maxm])
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.fill_between(k, lo, hi, color="tab:blue", alpha=0.25, label="R_a[k] (model)")
    ax.plot(k, ymax, color="tab:red", lw=1.2, label="max / min measured y_a over test cases")
    ax.plot(k, ymin, color="tab:red", lw=1.2)
    out = (ymax > hi) | (ymin < lo)
    if out.any():
        ax.plot(k[out], np.where(ymax[out] > hi[out], ymax[out], ymin[out]), "kx", label="outside")
    ax.set_xlabel("k (ticks after the test case's start)")
    ax.set_ylabel("y_a [rad]")
    ax.set_title(f"{name}: {devs.test_cases} test cases", fontsize=10)
    ax.legend(fontsize=8)
    p = d / f"deviations_{name}.png"
    _save(plt, fig, p)
    return str(p)
