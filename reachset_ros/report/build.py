"""What the report shows, computed from bags and a model by the core ``check`` and ``replay`` use.

Per bag (one task per bag, as a fleet run splits them, :mod:`reachset_ros.fleet`; test cases
never span two bags): the joints' series (:func:`reachset_ros.bags.read_joint_series`, the
reader of ``check``), per joint the set use of every tick and the violating ticks
(:func:`reachset_ros.conformance.set_use.set_use`, Theorem 1's checks as
:func:`~reachset_ros.conformance.theorem1.check` makes them), the deviation extremes for the
R_a figure (:func:`~reachset_ros.conformance.theorem1.deviation_extremes`, merged over the
bags exactly by :func:`~reachset_ros.conformance.theorem1.combine`, as ``check --plot`` draws
them), and the bag's safe stops and fault onsets (``/safe_stop``, ``/sim/fault_onset``).
Times are seconds from the bag's start: its first ``/joint_states`` sample (header stamps, the
clock the stops and the monitor's verdicts are stamped with).

Per joint of the model, the guarantee (:func:`guarantee_rows`): its inflation, the R*_e its
synthesis recorded, and ``R*_u`` inside ``U_p`` certified for the sets the monitor checks by
the gate the nodes run (:func:`reachset_ros.systems.gains.certify`, recorded U_e,ff).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import bags as bg
from ..conformance import model as mdl
from ..conformance.kernels import require_runs
from ..conformance.set_use import set_use
from ..conformance.theorem1 import combine, deviation_extremes
from ..errors import ReachsetError, first_line
from ..systems.gains import Gains, certify, model_limits

__all__ = ["BagEvent", "JointRun", "BagRun", "ReportData", "build_report", "guarantee_rows"]


@dataclass(frozen=True, kw_only=True)
class BagEvent:
    """A safe stop, a reset or a fault onset recorded in a bag."""

    kind: str            # "stop" | "reset" | "fault onset"
    stamp_ns: int
    t_s: float           # seconds from the bag's start
    joint: str = ""
    reason: str = ""


@dataclass(frozen=True, kw_only=True)
class JointRun:
    """One joint in one bag: its ticks' times, set use and violating ticks."""

    t_s: np.ndarray             # seconds from the bag's start, per tick
    use: np.ndarray             # set use per tick (NaN: nothing checked)
    violating: np.ndarray       # bool per tick
    stamps: np.ndarray          # header stamps, ns
    test_cases: int

    @property
    def violations(self):
        return int(self.violating.sum())

    def violation_times(self):
        """Seconds from the bag's start of the violating ticks."""
        return self.t_s[self.violating]


@dataclass(frozen=True, kw_only=True)
class BagRun:
    """What one bag holds for the report."""

    path: str
    start_ns: int
    joints: dict                 # name -> JointRun
    events: tuple                # BagEvent, in stamp order
    data: dict                   # the reader's report (ReadReport.as_dict)


@dataclass(frozen=True, kw_only=True)
class ReportData:
    """Everything the page shows (:func:`build_report`)."""

    model_path: str
    model: object
    thm: object                   # the model's Theorem-1 rows (ConformanceModel.theorem1)
    model_id: str
    joints: tuple
    runs: tuple                   # BagRun per bag
    devs: dict                    # joint -> Deviations over all bags (combine)
    guarantee: dict               # joint -> row dict (guarantee_rows)
    command: str = ""
    notes: list = field(default_factory=list)

    def summary(self):
        """The JSON summary of the report (the command's ``--json``)."""
        joints = {}
        for n in self.joints:
            runs = [(r, r.joints[n]) for r in self.runs if n in r.joints]
            first = next(((r.path, float(j.violation_times()[0])) for r, j in runs if j.violations), None)
            joints[n] = {"violations": sum(j.violations for _, j in runs),
                         "test_cases": sum(j.test_cases for _, j in runs),
                         "first_violation": None if first is None else {"bag": first[0], "t_s": first[1]},
                         "largest_set_use": _finite_max([j.use for _, j in runs])}
        return {"conformant": all(j["violations"] == 0 for j in joints.values()), "joints": joints,
                "stops": [{"bag": r.path, "t_s": e.t_s, "stamp_ns": e.stamp_ns, "joint": e.joint, "reason": e.reason}
                          for r in self.runs for e in r.events if e.kind == "stop"],
                "fault_onsets": [{"bag": r.path, "t_s": e.t_s, "stamp_ns": e.stamp_ns}
                                 for r in self.runs for e in r.events if e.kind == "fault onset"],
                "model_id": self.model_id}


def _finite_max(arrays):
    """The largest finite set use (None: nothing checked). An infinite use (a NaN deviation,
    which the bag reader's segments never hold) is a violation, counted there; JSON has no inf."""
    vals = [a[np.isfinite(a)] for a in arrays]
    vals = [v for v in vals if len(v)]
    return float(max(v.max() for v in vals)) if vals else None


def _events(bag, start_ns):
    """The safe stops, resets and fault onsets of a bag (small topics, decoded one by one)."""
    out = []
    try:
        for topic, _t, m in bg.read_messages([bag], [bg.SAFE_STOP_TOPIC, bg.FAULT_ONSET_TOPIC]):
            # a fault onset is a std_msgs/Header itself
            st = bg.header_stamp_ns(m) if topic == bg.SAFE_STOP_TOPIC else int(m.stamp.sec) * 10**9 + int(m.stamp.nanosec)
            if topic == bg.SAFE_STOP_TOPIC:
                kind = "stop" if m.active else "reset"
                out.append(BagEvent(kind=kind, stamp_ns=st, t_s=(st - start_ns) * 1e-9, joint=str(m.joint),
                                    reason=str(m.reason)))
            else:
                out.append(BagEvent(kind="fault onset", stamp_ns=st, t_s=(st - start_ns) * 1e-9))
    except ReachsetError:
        raise
    except Exception as e:     # rosbags' decoding errors have no common base class
        raise ReachsetError(f"{bag}: {bg.SAFE_STOP_TOPIC} or {bg.FAULT_ONSET_TOPIC} unreadable ({first_line(e)})") from e
    # the monitor republishes its latched stop: one event per (kind, stamp, joint, reason)
    return tuple(sorted({(e.kind, e.stamp_ns, e.joint, e.reason): e for e in out}.values(), key=lambda e: e.stamp_ns))


def _read_bag(bag, model, joints, topics, options):
    """``({joint: JointSeries}, ReadReport)`` of one bag, the model's joints (or ``joints``)."""
    series, report = bg.read_joint_series([Path(bag)], None if joints is None else list(joints), model.plant.dt,
                                          topics, **options)
    names = list(model.joints) if joints is None else list(joints)
    for n in names:
        if n not in model.joints:
            raise ReachsetError(f"joint {n} is not in the model")
        if n not in series:
            raise ReachsetError(f"{bag}: joint {n} of the model not found in the bag")
    return {n: series[n] for n in names}, report


def _bag_run(bag, model, thm, series, report):
    """The :class:`BagRun` of one bag's series and the per-joint deviation extremes."""
    start = min(int(s.stamps[0]) for s in series.values() if len(s.stamps))
    joints, devs = {}, {}
    for n, s in series.items():
        xi = model.checked_xi(n)
        su = set_use(model.plant, thm, model.estimator, xi, s.y, s.u, s.segments, model.horizon)
        joints[n] = JointRun(t_s=(np.asarray(s.stamps, np.int64) - start) * 1e-9, use=su.use,
                             violating=su.violating, stamps=np.asarray(s.stamps, np.int64), test_cases=su.test_cases)
        devs[n] = deviation_extremes(model.plant, model.estimator, s.y, s.u, s.segments, model.horizon, thm,
                                     allow_empty=True)
    return BagRun(path=str(bag), start_ns=start, joints=joints, events=_events(bag, start), data=report.as_dict()), devs


def guarantee_rows(model):
    """Per joint: its inflation, the R*_e its synthesis recorded and the certificate of R*_u
    inside U_p for the sets the monitor checks (:func:`reachset_ros.systems.gains.certify`,
    the gate of the nodes, with the joint's own inflation and the recorded U_e,ff); a joint
    without gains (a model from ``identify``) has no certificate."""
    rows = {}
    for n, js in model.joints.items():
        infl = model.joint_inflation(n)
        row = {"inflation": infl, "gains": None, "re_radius": None, "re_norm": None, "ru": None,
               "u_max": None, "certified": None, "reason": "no gains in the model (identify): no R*_e, R*_u"}
        g = dict(js.gains or {})
        if g:
            try:
                gains = Gains.from_model(g)
                u_max, u_ff = model_limits(js)
                c = certify(gains, js, infl, u_max, u_ff, plant=model.plant)
            except ReachsetError as e:
                row.update(reason=first_line(e))
            else:
                row.update(gains=_describe_gains(g), u_max=u_max, u_ff=u_ff, certified=bool(c.ok), reason=c.reason,
                           ru=None if c.ru is None else [float(c.ru[0]), float(c.ru[1])],
                           re_radius=[float(x) for x in g.get("re_radius", [])[:2]] or None,
                           re_norm=None if g.get("re_norm") is None else float(g["re_norm"]))
        rows[n] = row
    return rows


def _describe_gains(g):
    keys = [k for k in ("observer", "controller", "omega", "zeta", "h1", "h2", "h3", "eps", "l1", "l2", "l3") if k in g]
    return ", ".join(f"{k} {g[k]:.4g}" if isinstance(g[k], (int, float)) else f"{k} {g[k]}" for k in keys)


def build_report(bags, model, *, joints=None, topics=(bg.JOINT_STATES, bg.PLANT_INPUT), options=None, command="",
                 log=None):
    """The :class:`ReportData` of ``bags`` against the model file ``model``.

    Parameters
    ----------
    bags : sequence of path
        rosbag2 directories or bare storage files.
    model : path
        The model file (its SHA-256 prefix is the model id the monitor publishes).
    joints : sequence of str, optional
        Default: every joint of the model.
    topics : (measurement topic, plant-input topic)
    options : dict, optional
        ``read_joint_series`` options (``effort``, ``joint_names``), as ``check`` reads them.
    command : str
        The command line, shown in the provenance.
    log : callable, optional
        Progress lines (one per bag).
    """
    if not bags:
        raise ReachsetError("no bags given")
    options = dict(options or {})
    m = mdl.load(model)
    mdl.require_input_source(m, options.get("effort"), source=str(model))
    thm = m.theorem1()
    runs, devs, longest = [], {}, {}
    for i, bag in enumerate(bags):
        if log:
            log(f"[{i + 1}/{len(bags)}] {bag}")
        series, report = _read_bag(bag, m, joints, topics, options)
        run, d = _bag_run(bag, m, thm, series, report)
        runs.append(run)
        for n, s in series.items():
            devs.setdefault(n, []).append(d[n])
            longest[n] = max(longest.get(n, 0), max((b - a for a, b in s.segments), default=0))
    require_runs(longest, m.estimator.history, m.horizon, [str(b) for b in bags])
    names = tuple(runs[0].joints)
    return ReportData(model_path=str(model), model=m, thm=thm, model_id=mdl.file_sha256(model)[:12], joints=names,
                      runs=tuple(runs), devs={n: combine(v) for n, v in devs.items()}, guarantee=guarantee_rows(m),
                      command=command)
