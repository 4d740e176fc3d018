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


class _EnvelopeCount:
    """The monitor's envelope classification of replayed ticks
    (:class:`~reachset_ros.conformance.envelope.EnvelopeTracker`), counted per joint as
    ``check`` counts them (:func:`~reachset_ros.conformance.envelope.tick_counts`)."""

    def __init__(self, env, names):
        self.tracker = None if env is None or any(n not in env.joints for n in names) else \
            envelope.EnvelopeTracker(env, names)
        self.outside, self.inside_viol = np.zeros(len(names), np.int64), np.zeros(len(names), np.int64)
        self.classified = np.zeros(len(names), np.int64)

    def reset(self):
        if self.tracker is not None:
            self.tracker.reset()

    def tick(self, stamp, y, u, violating):
        if self.tracker is None:
            return
        out = self.tracker.tick(stamp, y, u)
        valid = bool(np.isfinite(y).all() and np.isfinite(u).all())
        self.classified += valid
        self.outside += out
        self.inside_viol += np.asarray(violating, dtype=bool) & ~out

    def counts(self, j):
        if self.tracker is None:
            return envelope.tick_counts(None, None, None, None)
        return {"outside_envelope_ticks": int(self.outside[j]), "violations_inside_envelope": int(self.inside_viol[j]),
                "classified_ticks": int(self.classified[j])}


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
        s0 = series[group[0]]
        Y = np.stack([series[n].y for n in group], axis=1)
        U = np.stack([series[n].u for n in group], axis=1)
        viol = np.zeros(len(group), dtype=np.int64)
        env = _EnvelopeCount(model.envelope, group)             # issue 37: the monitor's classification
        first = [None] * len(group)
        checks = np.zeros(len(group), dtype=np.int64)
        d = np.empty(len(s0.stamps))
        use = np.full((len(s0.stamps), len(group)), np.nan)
        cut = breaks[group[0]]
        for i in range(len(s0.stamps)):
            t0 = time.perf_counter()
            if i in cut:
                mon.reset()
                env.reset()
            r = mon.tick(int(s0.stamps[i]), Y[i], U[i])
            d[i] = time.perf_counter() - t0
            if isinstance(r, dict):
                status, checked, use[i] = r["status"], r["checked"], r["use"]
            else:
                status, checked, use[i] = [r.status], [r.checked], r.use
            env.tick(int(s0.stamps[i]), Y[i], U[i], [st == "violation" for st in status])
            for j, st in enumerate(status):
                checks[j] += checked[j]
                if st == "violation":
                    viol[j] += 1
                    if first[j] is None:
                        first[j] = int(s0.stamps[i])
        durs.append(d)
        for j, n in enumerate(group):
            starts = test_case_starts(series[n].segments, model.estimator.history)[0]
            finite = use[:, j][np.isfinite(use[:, j])]
            out[n] = {"violations": int(viol[j]), "first_violation_ns": first[j],
                      "test_cases": int(len(starts)), "checks": int(checks[j]), **env.counts(j),
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
