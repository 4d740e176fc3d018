"""``reachset replay``: the bag through the online monitor's tick-by-tick code path.

The test cases are cut exactly where ``reachset check`` cuts them: at the boundaries of the
series' segments (:func:`reachset_ros.bags.series.read_joint_series`, the one source of
truth). The monitor itself ends a segment at a stamp gap or an invalid sample; where two
segments touch without either (the next bag stamped one tick after the previous one, see
:func:`segment_breaks`), replay resets the monitor, so that a test case never continues
into another recording.
"""
import time

import numpy as np

from ..conformance import envelope
from ..conformance import model as mdl
from ..conformance.kernels import test_case_starts
from ..conformance.monitor import JointMonitor, Monitor, MonitorModel
from ..errors import ReachsetError
from . import emit, help_of
from ._bagargs import add_bag_arguments, load_series, require_horizon, reader_options, topics_of
from ._progress import bag_count, progress

NAME = "replay"
HELP = help_of(NAME)


def add_arguments(p):
    add_bag_arguments(p)
    p.add_argument("--model", required=True, help="model YAML (identify/synthesize output)")


def segment_breaks(segments):
    """Ticks at which one segment ends and the next begins at once (no invalid tick between).

    Each bag starts a new segment, so these are the bag boundaries (and stamp gaps, where
    the monitor resets anyway): the ticks before which the monitor must forget its test
    cases to agree with ``check``.
    """
    return {b for (_, b), (c, _) in zip(segments, segments[1:]) if b == c}


def _tick_all(mon, stamps, Y, U, cut):
    """Every tick of a group through the monitor ``mon``, reset before each tick in ``cut``.

    Returns per tick and joint the status (index into ``Monitor.STATUS``), the test cases
    checked and the set use, and per tick its duration in seconds. A :class:`Monitor` runs each
    stretch between resets in one :meth:`~reachset_ros.conformance.monitor.Monitor.tick_many`
    (with the compiled kernel: its tick function in a C loop, each tick timed there); a
    :class:`JointMonitor` tick by tick.
    """
    T, J = Y.shape[:2]
    status, checked = np.zeros((T, J), np.int8), np.zeros((T, J), np.int64)
    use, secs = np.full((T, J), np.nan), np.zeros(T)
    bounds = [0, *sorted(c for c in cut if 0 < c < T), T]
    for a, b in zip(bounds[:-1], bounds[1:]):
        if a > 0:
            mon.reset()
        if isinstance(mon, Monitor):
            r = mon.tick_many(stamps[a:b], Y[a:b], U[a:b])
            status[a:b], checked[a:b], use[a:b], secs[a:b] = r["status"], r["checked"], r["use"], r["seconds"]
            continue
        for i in range(a, b):
            t0 = time.perf_counter()
            r = mon.tick(int(stamps[i]), Y[i], U[i])
            secs[i] = time.perf_counter() - t0
            status[i, 0], checked[i, 0], use[i, 0] = Monitor.STATUS.index(r.status), r.checked, r.use
    return status, checked, use, secs


def _envelope_counts(env, names, stamps, Y, U, cut, violating):
    """Per joint the envelope's counts of the replayed ticks (``check``'s
    :func:`~reachset_ros.conformance.envelope.tick_counts` keys) from the monitor's classification
    (:func:`~reachset_ros.conformance.envelope.track`, restarted at each tick of ``cut`` as the
    monitor is reset there); None when the model records no envelope for some joint."""
    if env is None or any(n not in env.joints for n in names):
        return [envelope.tick_counts(None, None, None, None) for _ in names]
    T = len(stamps)
    bounds = [0, *sorted(c for c in cut if 0 < c < T), T]
    out = np.concatenate([envelope.track(env, names, stamps[a:b], Y[a:b], U[a:b]) for a, b in zip(bounds[:-1],
                                                                                                 bounds[1:])])
    classified = int((np.isfinite(Y).all(axis=1) & np.isfinite(U).all(axis=1)).sum())
    return [{"outside_envelope_ticks": int(out[:, j].sum()),
             "violations_inside_envelope": int((violating[:, j] & ~out[:, j]).sum()),
             "classified_ticks": classified} for j in range(len(names))]


def replay_joints(model, series, thm=None, uses=None):
    """Feed the series tick by tick to the online monitor; returns per-joint results, durations.

    Each joint's result has ``largest_set_use``: the largest finite set use of its ticks (the
    monitor's ``use``, ConformanceStatus.set_use; None: nothing checked). ``uses``, a dict,
    receives each joint's set use per tick (NaN: nothing checked), equal to the batch side's
    :func:`reachset_ros.conformance.set_use.set_use` to the bit.

    Joints with one-dimensional outputs, identical stamps and identical segment breaks run
    together in one :class:`~reachset_ros.conformance.monitor.Monitor` (the monitor node's code
    path); otherwise each joint runs on its own (a ``Monitor`` of one joint, or a
    ``JointMonitor`` for multi-dimensional outputs).
    """
    names = list(series)
    mms = [MonitorModel.from_model(model, n, thm) for n in names]
    first_stamps = series[names[0]].stamps
    breaks = {n: segment_breaks(series[n].segments) for n in names}
    together = (all(m.scalar for m in mms) and all(np.array_equal(series[n].stamps, first_stamps) for n in names)
                and all(breaks[n] == breaks[names[0]] for n in names))
    groups = [names] if together else [[n] for n in names]
    out, durs = {}, []
    for group in groups:
        ms = [mms[names.index(n)] for n in group]
        mon = Monitor(ms) if all(m.scalar for m in ms) else JointMonitor(ms[0])
        stamps = np.asarray(series[group[0]].stamps, dtype=np.int64)
        Y = np.stack([np.reshape(series[n].y, len(stamps)) if ms[0].scalar else series[n].y for n in group], axis=1)
        U = np.stack([np.reshape(series[n].u, len(stamps)) if ms[0].scalar else series[n].u for n in group], axis=1)
        cut = breaks[group[0]]
        status, checked, use, secs = _tick_all(mon, stamps, Y, U, cut)
        durs.append(secs)
        violating = status == Monitor.STATUS.index("violation")
        env = _envelope_counts(model.envelope, group, stamps, Y, U, cut, violating)
        for j, n in enumerate(group):
            starts = test_case_starts(series[n].segments, model.estimator.history)[0]
            finite = use[:, j][np.isfinite(use[:, j])]
            hit = np.flatnonzero(violating[:, j])
            out[n] = {"violations": int(len(hit)), "first_violation_ns": int(stamps[hit[0]]) if len(hit) else None,
                      "test_cases": int(len(starts)), "checks": int(checked[:, j].sum()), **env[j],
                      "largest_set_use": float(finite.max()) if len(finite) else None}
            if uses is not None:
                uses[n] = use[:, j].copy()
    return out, durs, together


def run(args):
    model = mdl.load(args.model)
    options = reader_options(args)
    mdl.require_input_source(model, options["effort"], source=args.model)   # u_p as the model's (34.10)
    with progress(args) as p:
        p.phase(f"reading {bag_count(args.bags)}")
        series, report = load_series(args.bags, args.joints, model.plant.dt, restrict=list(model.joints),
                                     topics=topics_of(args), options=options)
        require_horizon(series, model.estimator.history, model.horizon, args.bags)
        thm = model.theorem1()
        missing = [n for n in series if n not in model.joints]
        if missing:
            raise ReachsetError(f"joint {missing[0]} is not in the model {args.model}")
        p.phase(f"replaying {len(series)} joint{'' if len(series) == 1 else 's'} tick by tick through the monitor")
        joints, durs, together = replay_joints(model, series, thm)
    ticks = max(len(s.stamps) for s in series.values())
    d = np.concatenate(durs) * 1e6 if durs else np.zeros(1)
    result = {"conformant": all(j["violations"] == 0 for j in joints.values()), "joints": joints,
              "ticks": ticks, "timing_us_per_tick": {"mean": float(d.mean()), "p99": float(np.percentile(d, 99)),
                                     "max": float(d.max()), "joints_per_tick": len(series) if together else 1},
              "data": report.as_dict(), "envelope": envelope.summary(model.envelope)}
    emit(args, result, ("conformant" if result["conformant"] else "NOT conformant") + "\n" + "\n".join(
        f"{n}: {j['violations']} violating ticks" for n, j in joints.items())
        + f"\n{ticks} ticks, {d.mean():.0f} us mean per tick")
    return 0 if result["conformant"] else 1      # 1: not conformant (a CI gate), 2: bad input
