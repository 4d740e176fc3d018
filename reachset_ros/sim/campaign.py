"""The fault campaign's schedule and its score (issue 17): pure data, no ROS.

A campaign is a seeded list of :class:`Event` s, each preceded by a fault-free stretch of
monitored running; :func:`schedule` draws it, :func:`score` turns what the runner observed
(:class:`Outcome` per event) into the campaign's one table (:func:`table`).

What each event is expected to do (``Event.expect``):

* ``stop``: a fault that must stop the arm. Every fault kind of the simulator on every
  joint (magnitudes in :data:`SIM_FAULTS`, beyond what the identified sets allow), a killed
  process (SIGKILL of the observer, controller or simulator: its data stop, the monitor's
  watchdog stops), a sample whose stamp jumps back (a second publisher on
  ``/joint_states``: the monitor's ``stamp_backwards`` fault). A missed stop is an event of
  this kind with no new active stop within :data:`DETECT_WITHIN_S` of simulated time
  (``DETECT_WITHIN_WALL_S`` of wall time for a killed process, whose clock may stop). A
  frozen sensor changes nothing while its joint rests: its window (and its latency) starts
  at the first reference motion of the joint after the fault that lasts the stuck-sensor
  rule's :data:`FROZEN_RUN` ticks (:data:`FROZEN_MOTION`, :func:`frozen_observable_ns`); a
  joint that does not move so within :data:`FROZEN_WAIT_S` makes the event ``unobservable``
  (reported, neither a stop nor a miss).
* ``none``: a perturbation the system must ride through: a process frozen (SIGSTOP, then
  SIGCONT) for less than :data:`FREEZE_TOLERATED_S`; the simulator waits for its command
  (lockstep) and every topic is queued. Any stop then, or in the fault-free stretch before
  an event, is a false stop.
* ``link`` events (the relay between ``/joint_states`` and the monitor,
  :mod:`reachset_ros.nodes.relay_node`): ``loss`` (half the samples dropped at random until the
  stop) must stop -- the monitor loses samples again and again and can no longer form test
  cases of k* steps (its ``coverage`` fault); ``sparse`` (one sample in :data:`SPARSE_EVERY` dropped, for :data:`LINK_S`) and
  ``delay`` (10-80 ms added to every sample, order kept, for :data:`LINK_S`) must not.
* ``either``: a freeze of :data:`FREEZE_TOLERATED_S` or longer (up to 0.5 s): the simulator
  holds a stale command and the catch-up may exceed the monitor's 0.5 s missing-data limit,
  so a stop is allowed; counted apart.

The stop latency is measured from the fault's stamp (the simulator's first affected
measurement, ``/sim/fault_onset``; for a process fault or a stamp jump the simulation's
time when it was injected) to the stop's arrival at the campaign's listener, on the
simulation's clock; the stamp the stop carries is reported too.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from ..robot.dynamics import JOINT_NAMES, TABLE1_TAU_MAX

__all__ = ["Event", "Outcome", "SIM_FAULTS", "schedule", "score", "table", "DETECT_WITHIN_S", "LOSS_SHARE", "LOSS_DETECT_S", "detect_within_s",
           "SPARSE_EVERY", "DELAY_S", "LINK_S",
           "DETECT_WITHIN_WALL_S", "FREEZE_TOLERATED_S", "KILLABLE", "FREEZABLE", "judge_rest"]

#: a fault that must stop is missed when no stop arrives within this much simulated time
DETECT_WITHIN_S = 1.0
#: ... for a link ``loss``: the monitor's horizon rule allows its warm-up plus its
#: missing-data limit (3 + 125 + 125 ticks = 1.012 s in the campaign) before the stop; its
#: lossy-link rule (``gap_window``, since the fifth long run) stops at the second loss, but
#: the window stays as it was so that earlier runs are scored alike
LOSS_DETECT_S = 2.0
#: ... or this much wall time (a killed or frozen simulator stops the simulation's clock)
DETECT_WITHIN_WALL_S = 5.0
#: a frozen sensor is observable only once its joint moves: the detection window starts at the
#: first reference with |qd_d| above this (rad/s) after the fault ...
FROZEN_MOTION = 0.05
#: ... that begins a run of this many consecutive ticks above it: the monitor's stuck-sensor rule
#: (:class:`~reachset_ros.conformance.watches.StuckSensorWatch`, the node's ``stuck_ticks`` 5)
#: needs the reading repeated on 5 + 1 consecutive ticks while the reference moves. The tail of
#: a move that ends fewer ticks after the fault gives no such evidence, and the joint then rests
#: with the reading within about 1 mrad of the truth. Since 2026-11-28: the long
#: campaign's event 44 (session 26) was counted late from such a tail, 2.8 s before the rule's
#: first chance (docs/reliability.md).
FROZEN_RUN = 6
#: ... awaited this long (simulated s); a joint whose reference does not move is reported
#: as ``unobservable``, neither stopped nor missed
FROZEN_WAIT_S = 10.0
#: freezes shorter than this must not stop: the simulator's lockstep timeout (0.3 s). A longer
#: freeze makes it hold a stale command, and the process' catch-up after SIGCONT can then
#: exceed the monitor's 0.5 s missing-data limit (a 376 ms freeze of the observer did so once
#: in `make test`: /plant_input silent 503 ms); 0.3-0.5 s: a stop is allowed
FREEZE_TOLERATED_S = 0.3
#: link events: the share of samples a ``loss`` drops, the one-in-n of a ``sparse`` loss (more
#: than the monitor's warm-up of 128 ticks plus its 25-tick missing-data limit apart, so test
#: cases reach k* between two losses), the range of a ``delay`` (s) and how long the tolerated
#: link faults last (simulated s)
LOSS_SHARE = 0.5
SPARSE_EVERY = 200
DELAY_S = (0.01, 0.08)
LINK_S = 3.0
#: processes the campaign kills (SIGKILL) and restarts
KILLABLE = ("observer_node", "controller_node", "sim_node")
#: processes the campaign freezes (SIGSTOP for 50-500 ms, then SIGCONT)
FREEZABLE = ("observer_node", "controller_node", "sim_node", "monitor_node", "reference_node")


def _sim_faults():
    """(kind, joint, magnitude) of every simulator fault kind on every joint: an
    acceleration of 30 rad/s^2 (beyond u_max), half the joint's Table I torque, a sensor bias
    of 0.01 rad, a frozen sensor, 3 NaN samples; a 5 kg payload (all joints)."""
    out = [("payload", JOINT_NAMES[-1], 5.0)]
    for j, name in enumerate(JOINT_NAMES):
        out += [("acceleration", name, 30.0), ("torque", name, 0.5 * float(TABLE1_TAU_MAX[j])),
                ("bias", name, 0.01), ("frozen", name, 0.0), ("nan", name, 3.0)]
    return tuple(out)


SIM_FAULTS = _sim_faults()


@dataclass(frozen=True)
class Event:
    """One scheduled event: ``quiet_s`` s of fault-free running, then the fault.

    ``kind``: ``sim`` (``fault``, ``joint``, ``magnitude``), ``kill`` (``target``),
    ``freeze`` (``target``, ``seconds``), ``stamp_jump`` (``seconds`` back), ``link``
    (``fault``: loss, sparse or delay; ``magnitude``: the drop share, one-in-n or delay in s;
    ``seconds``: how long) or ``quiet`` (nothing: a longer fault-free stretch). ``burners``: CPU burners on both cores run
    during the event and the stretch before it."""

    index: int
    kind: str
    quiet_s: float
    expect: str                  # stop | none | either
    burners: bool = False
    target: str = ""
    fault: str = ""
    joint: str = ""
    magnitude: float = 0.0
    seconds: float = 0.0

    def label(self):
        if self.kind == "sim":
            return f"sim {self.fault} {self.joint} {self.magnitude:g}"
        if self.kind == "kill":
            return f"kill {self.target}"
        if self.kind == "freeze":
            return f"freeze {self.target} {self.seconds * 1e3:.0f} ms"
        if self.kind == "stamp_jump":
            return f"stamp jump back {self.seconds * 1e3:.0f} ms"
        if self.kind == "link":
            what = {"loss": f"{self.magnitude:.0%} dropped", "sparse": f"1 in {self.magnitude:.0f} dropped",
                    "delay": f"{self.magnitude * 1e3:.0f} ms delay"}.get(self.fault, self.fault)
            return f"link {self.target}: {what}"
        return f"quiet {self.quiet_s:g} s"


@dataclass
class Outcome:
    """What the runner saw for one event (stamps in ns of the simulation's clock)."""

    event: Event
    fault_ns: int = 0                 # the fault's stamp
    stops: list = field(default_factory=list)   # (stop stamp, arrival sim ns, reason) of new active stops
    quiet_stops: list = field(default_factory=list)   # the same, in the fault-free stretch before
    quiet_sim_s: float = 0.0          # fault-free monitored time before the event (simulated s)
    wall_latency_s: float = None      # wall time from injection to the stop's arrival
    braking_ticks: float = None       # controller: first braking command - newest estimate at the stop's arrival
    recovery_stops: int = 0           # stops while recovering (after a reset), not scored
    resets_refused: int = 0           # resets the monitor refused (the stop's condition persisted)
    reset_ns: int = 0                 # the simulation's time when the reset after the stop succeeded
    rest: dict = None                 # the stop's effect from the bag (:func:`judge_rest`)
    stale_steps: int = 0              # simulator steps on a stale command during the event (its /diagnostics)
    ahead_steps: int = 0              # simulator steps ahead of the monitor's verdicts during the event (ditto)
    #: where the fault becomes observable, if later than fault_ns: a frozen sensor's joint's
    #: first reference motion after the fault; a link loss's first lost sample (from the bag,
    #: workflows.campaign.link_onsets)
    observable_ns: int = 0
    #: frozen sensor stopped while its joint's reference never exceeded FROZEN_MOTION after the
    #: fault (a slow move: the stop came before the window starts, so it cannot be late; the
    #: latency still counts from the fault)
    stopped_before_motion: bool = False
    #: the stop's arrival at the controller, bounded from above: the stamp of the first
    #: measurement the controller commanded with the stop (``BrakeCommand.braking_since_ns``
    #: from the bag, workflows.campaign.bag_brakes). In lockstep the simulation cannot step past
    #: the measurement whose command the controller owes, so the stop reached the controller
    #: before the simulation's clock passed this stamp. 0: no braking command (killed
    #: controller or simulator, or none recorded)
    controller_ns: int = 0
    bag: str = ""                     # the bag holding the event
    note: str = ""

    def latency_from(self):
        """The stamp latencies count from: the fault's, or for a frozen sensor the first
        motion of its joint's reference after it (the fault is not observable before), for a
        link loss its first lost sample."""
        return self.observable_ns or self.fault_ns

    def evidence_from(self):
        """The later of the first stop's own stamp and :meth:`latency_from` (a stamp jump's stop
        carries the jumped, earlier stamp: its evidence is the fault's); needs a stop."""
        return max(self.stops[0][0], self.latency_from())

    def latency_ns(self):
        """The first stop's arrival after :meth:`latency_from` (needs a stop)."""
        return self.stops[0][1] - self.latency_from()

    def acted_latency_ns(self):
        """The first stop's earliest known arrival where it acts, after :meth:`latency_from`
        (needs a stop): the controller's (:attr:`controller_ns`, itself an upper bound) when the
        bag has it, else the listener's (:meth:`latency_ns`). A stop is judged by its effect: the
        campaign's listener is a normal-priority process the burners starve (the long campaign's
        event 132: braked 20 ms after the fault, received by the listener at 1,288 ms)."""
        arrival = min(self.stops[0][1], self.controller_ns) if self.controller_ns else self.stops[0][1]
        return arrival - self.latency_from()

    def as_dict(self):
        d = asdict(self)
        d["event"] = self.event.label()
        return d


def detect_within_s(event):
    """The detection window of an event that must stop, simulated s (:data:`DETECT_WITHIN_S`,
    :data:`LOSS_DETECT_S` for a link loss)."""
    return LOSS_DETECT_S if event.kind == "link" and event.fault == "loss" else DETECT_WITHIN_S


def schedule(seed: int, n_events: int, quiet_s=(2.0, 6.0), burner_share=0.5, kinds=None, sim_faults=None):
    """A seeded campaign of ``n_events`` events.

    The faults cycle through every simulator fault on every joint (:data:`SIM_FAULTS`), every
    killable process, freezes of every freezable process (50-500 ms, uniform), stamp
    jumps (0.1-1 s back) and link faults (loss, sparse loss, delay), in a seeded random order, one kind after another so that each
    kind is reached early; one event in eight is ``quiet``. Before each event a fault-free
    stretch drawn uniformly from ``quiet_s`` (simulated s). The CPU burners run in
    alternating blocks of 8 events, ``burner_share`` of them on.

    Parameters
    ----------
    seed : int
    n_events : int
    quiet_s : (float, float)
    burner_share : float
        0 (never), 0.5 (every other block) or 1 (always).
    kinds : iterable of str, optional
        Restrict to these event kinds (``sim``, ``kill``, ``freeze``, ``stamp_jump``, ``link``, ``quiet``).
    sim_faults : iterable of str, optional
        Restrict the simulator faults to these kinds (``acceleration``, ``frozen``, ...).

    Returns
    -------
    list of Event
    """
    rng = np.random.default_rng(seed)
    pools = {
        "sim": [dict(fault=f, joint=j, magnitude=m) for f, j, m in SIM_FAULTS
                if sim_faults is None or f in sim_faults],
        "kill": [dict(target=t) for t in KILLABLE],
        "freeze": [dict(target=t) for t in FREEZABLE],
        "stamp_jump": [dict()],
        "link": [dict(fault=f, target="/joint_states -> monitor") for f in ("loss", "sparse", "delay")],
        "quiet": [dict()],
    }
    weights = {"sim": 4, "kill": 1, "freeze": 2, "stamp_jump": 1, "link": 1}
    if kinds is not None:
        kinds = set(kinds)
        unknown = kinds - set(pools)
        if unknown:
            raise ValueError(f"unknown event kinds {sorted(unknown)}; known: {sorted(pools)}")
        pools = {k: v for k, v in pools.items() if k in kinds}
        weights = {k: v for k, v in weights.items() if k in kinds}
    order = {k: list(rng.permutation(len(v))) for k, v in pools.items()}
    cycle = [k for k, w in weights.items() for _ in range(w)]
    events = []
    for i in range(n_events):
        if "quiet" in pools and (i % 8 == 7 or not cycle):
            kind = "quiet"
        else:
            kind = cycle[int(rng.integers(len(cycle)))] if i >= len(weights) else list(weights)[i]
        if not order[kind]:
            order[kind] = list(rng.permutation(len(pools[kind])))
        spec = dict(pools[kind][order[kind].pop(0)])
        block_on = (i // 8) % 2 == 0 if burner_share == 0.5 else burner_share >= 1
        q = float(rng.uniform(*quiet_s))
        if kind == "freeze":
            spec["seconds"] = round(float(rng.uniform(0.05, 0.5)), 3)
            expect = "none" if spec["seconds"] < FREEZE_TOLERATED_S else "either"
        elif kind == "stamp_jump":
            spec["seconds"] = round(float(rng.uniform(0.1, 1.0)), 3)
            expect = "stop"
        elif kind == "link":
            f = spec["fault"]
            spec["magnitude"] = {"loss": LOSS_SHARE, "sparse": float(SPARSE_EVERY),
                                 "delay": round(float(rng.uniform(*DELAY_S)), 3)}[f]
            spec["seconds"] = 0.0 if f == "loss" else LINK_S
            expect = "stop" if f == "loss" else "none"
        elif kind == "quiet":
            expect = "none"
        else:
            expect = "stop"
        events.append(Event(index=i, kind=kind, quiet_s=round(q, 3), expect=expect, burners=bool(block_on), **spec))
    return events


def frozen_observable_ns(refs, fault_ns, run=FROZEN_RUN):
    """The stamp from which a frozen sensor is observable: the first reference of its joint
    after ``fault_ns`` moving faster than :data:`FROZEN_MOTION` in a run of ``run``
    consecutive ticks (None: no such run).

    Before it the frozen reading is the truth (the joint rests) or stays within the noise (it
    creeps, or the tail of a move ends within fewer ticks), so no sound monitor can tell it from
    a healthy reading; from it on the monitor's stuck-sensor rule (``stuck_speed``,
    ``stuck_ticks``) and the sets can. This is the detection limit of the class
    (``notes/detection-limit.md``: "say for each class what bounds it"); the campaign (its
    detection window) and the demo (its latency promise) count from here. The run may begin on
    the tick before the fault: the rule's repeated readings start with the reading the freeze
    holds, that tick's; the window then starts at the run's first reference after the fault.
    Ticks are consecutive when their stamps are at most 1.5 reference periods apart (the
    median step of the joint's references).

    Parameters
    ----------
    refs : list of Reference
        The joint's recorded references (:func:`reachset_ros.bags.read_references`; anything
        with ``stamps`` (ns) and ``qd`` arrays), any order.
    fault_ns : int
        The fault's stamp (``/sim/fault_onset``).
    run : int
        Consecutive ticks the motion must last (:data:`FROZEN_RUN`; 1: the first fast
        reference, the rule before 2026-11-28).

    Returns
    -------
    int or None
    """
    hits = []
    for r in refs:
        st = np.asarray(r.stamps, dtype=np.int64)
        qd = np.asarray(r.qd, dtype=np.float64)
        if st.size == 0:
            continue
        order = np.argsort(st, kind="stable")
        st, qd = st[order], qd[order]
        period = int(np.median(np.diff(st))) if st.size > 1 else 0
        keep = st >= fault_ns - period if period > 0 else st > fault_ns
        st, fast = st[keep], np.abs(qd[keep]) > FROZEN_MOTION
        n = 0
        for i in range(st.size):
            if not fast[i]:
                n = 0
                continue
            n = n + 1 if (n and 2 * (st[i] - st[i - 1]) <= 3 * period) else 1
            if n >= run and st[i] > fault_ns:
                after = st[i - n + 1:i + 1]
                hits.append(int(after[after > fault_ns][0]))
                break
    return min(hits) if hits else None


def judged_columns(fault, joint, names):
    """Indices into ``names`` of the joints whose recorded readings can show a stop's effect:
    all but the joint of a ``frozen`` sensor fault (its readings hold their last value whatever
    the arm does; the arm's true state is not recorded). The demo and the campaign judge a stop
    through this one rule."""
    return [j for j, n in enumerate(names) if not (fault == "frozen" and n == joint)]


def judge_rest(event, names, stamps_ns, q, qd, stop_ns, until_ns):
    """The stop's effect, read from the recorded ``/joint_states`` between the stop's stamp
    and ``until_ns`` (the reset): every joint at rest (abs(qd) < 0.01 rad/s to the end)
    within :data:`~reachset_ros.sim.safe_stop.REST_WITHIN_S` of the stop, having moved at most
    :data:`~reachset_ros.sim.safe_stop.TRAVEL_WITHIN_RAD` (the stated effect of a category-1
    stop, :func:`~reachset_ros.systems.stopping.rest_after_stop`). The joint of a frozen
    sensor cannot show rest and is not judged (the arm's true state is not recorded; the
    stop law on the true state is checked by test/systems/test_stopping.py). Returns a dict
    (``ok``, ``rest_s``, ``travel_rad``, ``judged``, ``seconds``, ``why``); ``ok`` None when
    the reset came less than ``REST_WITHIN_S`` after the stop (nothing to judge). The 3 NaN
    samples of a ``nan`` fault are left out (they are the sensor fault, not the arm's motion)."""
    from ..systems.stopping import rest_after_stop
    from .safe_stop import REST_WITHIN_S, TRAVEL_WITHIN_RAD
    stamps_ns = np.asarray(stamps_ns, np.int64)
    keep = (stamps_ns >= stop_ns) & (stamps_ns <= until_ns)
    judged = judged_columns(event.fault if event.kind == "sim" else None, event.joint, names)
    q, qd = np.asarray(q, float), np.asarray(qd, float)
    if event.kind == "sim" and event.fault == "nan":
        # the fault's own samples (NaN by design) are the sensor's, not the arm's motion
        keep &= np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(qd), axis=1)
    if keep.sum() < 2:
        return {"ok": False, "why": "no samples between the stop and the reset", "judged": len(judged)}
    if (min(int(until_ns), int(stamps_ns[keep][-1])) - stop_ns) * 1e-9 < REST_WITHIN_S:
        return {"ok": None, "why": f"not judged: the reset came {(until_ns - stop_ns) * 1e-9:.3f} s after the stop "
                                   f"(less than {REST_WITHIN_S:g} s)", "judged": 0}
    q, qd = q[keep][:, judged], qd[keep][:, judged]
    rep = rest_after_stop([names[j] for j in judged], stamps_ns[keep], q, qd, stop_ns)
    fails = rep.failures(REST_WITHIN_S, TRAVEL_WITHIN_RAD)
    rest = [r for r in rep.rest_s if r is not None]
    return {"ok": not fails, "why": "; ".join(map(str, fails))[:300],
            "rest_s": max(rest) if len(rest) == len(rep.rest_s) else None,
            "travel_rad": max(rep.travel), "judged": len(judged), "seconds": rep.seconds_after}


def _pct(x, p):
    return float(np.percentile(np.asarray(x, float), p)) if len(x) else None


def score(outcomes, apparatus_stops=()):
    """The campaign's table from the outcomes.

    Returns
    -------
    dict
        ``faults_injected`` (events expecting a stop), ``stops`` (of those, stopped within
        the event's detection window, :func:`detect_within_s`, judged where the stop acts:
        :meth:`Outcome.acted_latency_ns`), ``missed_stops`` (no stop, or one after the window), ``false_stops`` (a stop in a fault-free stretch or after an event
        expecting none), ``either`` (tolerance-band freezes: events, stops),
        ``fault_free_minutes`` (monitored, simulated), ``latency_ms`` (p50/p99/max of the
        arrival on the simulation's clock after the fault's stamp, every fault whose stop
        arrived, late ones included),
        ``latency_ms_by_kind``, ``stamp_latency_ms`` (the stop's own stamp: the first
        measurement outside the model's sets, or the tick at which a data rule's allowance ran
        out) and ``stamp_latency_ms_by_kind``, ``detection_ms`` (the stop's arrival after the later
        of its own stamp and the fault's: the monitor's detection and the delivery, the part of
        the latency that is the monitor's and not the fault's physics; ``detection_ms_burners``
        and ``detection_ms_quiet`` split it by the CPU burners), ``wall_latency_ms``
        for killed processes, ``braking_ticks_max`` (first braking command after the stop's
        arrival at the controller, ticks; killed controllers excluded), ``misses`` and
        ``false`` (each with its event, stamps and bag). ``controller_latency_ms`` (and
        ``_by_kind``): the stop's arrival at the controller, the node that acts on it
        (:attr:`Outcome.controller_ns`, an upper bound), after the fault's stamp, every stop
        that arrived but a killed controller's or simulator's (the drives' watchdog brakes
        those); ``controller_detection_ms`` (``_burners``, ``_quiet``): the same after the
        later of the stop's own stamp and the fault's; ``controller_unmeasured``: stops of
        that set with no braking command in the bag. The ``latency_ms`` and ``detection_ms``
        above are the arrival at the campaign's listener, a normal-priority process that the
        burners also starve.
    """
    unobservable = [o for o in outcomes if o.event.expect == "stop" and o.note.startswith("unobservable")]
    faults = [o for o in outcomes if o.event.expect == "stop" and o not in unobservable]
    arrived = [o for o in faults if o.stops]
    # a stop that arrived after the event's detection window is a missed stop (the runner
    # keeps whatever stop it has when it stops waiting, possibly a later one)
    # (a frozen sensor stopped before its joint moved at > FROZEN_MOTION: its window had not
    # begun, so the stop is not late; reported apart with its latency from the fault)
    # late: judged where the stop acts, the controller when the bag shows its braking
    # (Outcome.acted_latency_ns), else the listener
    late = [o for o in arrived
            if not o.stopped_before_motion and o.acted_latency_ns() > detect_within_s(o.event) * 1e9]
    stopped = [o for o in arrived if o not in late]
    missed = [o for o in faults if not o.stops] + late
    false = _false_stops(outcomes)
    either = [o for o in outcomes if o.event.expect == "either"]
    return {
        "events": len(outcomes),
        "faults_injected": len(faults),
        "unobservable": [o.event.label() for o in unobservable],
        "stopped_before_motion": [{"event": o.event.label(), "latency_ms": o.latency_ns() * 1e-6}
                                  for o in arrived if o.stopped_before_motion],
        "stops": len(stopped),
        "missed_stops": len(missed),
        "false_stops": len(false),
        "either": {"events": len(either), "stopped": sum(1 for o in either if o.stops)},
        "fault_free_minutes": sum(o.quiet_sim_s for o in outcomes) / 60.0,
        "burner_events": sum(1 for o in outcomes if o.event.burners),
        **_latency_rows(arrived),
        **_controller_rows(arrived),
        **_braking_rows(stopped),
        **_rest_rows(outcomes),
        **_step_rows(outcomes),
        "apparatus_stops": [list(a) for a in apparatus_stops],
        "misses": [{"event": o.event.label(), "fault_ns": o.fault_ns, "bag": o.bag,
                    "note": (f"stop {o.acted_latency_ns() * 1e-6:.0f} ms after the fault's stamp, "
                             f"after the {detect_within_s(o.event):g} s window" if o in late else o.note)}
                   for o in missed],
        "false": false,
    }


def _stats(x):
    return {"n": len(x), "p50": _pct(x, 50), "p99": _pct(x, 99), "max": max(x) if x else None}


def _false_stops(outcomes):
    """The false stops of :func:`score`: in a fault-free stretch, or after an event expecting none."""
    false = []
    for o in outcomes:
        for s in o.quiet_stops:
            false.append({"event": o.event.label(), "where": "fault-free stretch before it", "stop": list(s),
                          "bag": o.bag})
        if o.event.expect == "none" and o.stops:
            false.append({"event": o.event.label(), "where": "after the event", "stop": list(o.stops[0]),
                          "bag": o.bag})
    return false


def _latency_rows(arrived):
    """:func:`score`'s latencies at the listener of every stop that arrived, late ones included."""
    lat = [o.latency_ns() * 1e-6 for o in arrived]
    stamp_lat = [(o.stops[0][0] - o.latency_from()) * 1e-6 for o in arrived]
    detection = [(o.stops[0][1] - o.evidence_from()) * 1e-6 for o in arrived]
    by_kind, stamp_by_kind = {}, {}
    for o, x, y in zip(arrived, lat, stamp_lat):
        key = _kind_key(o.event)
        by_kind.setdefault(key, []).append(x)
        stamp_by_kind.setdefault(key, []).append(y)
    return {
        "latency_ms": _stats(lat),
        "latency_ms_by_kind": {k: _stats(v) for k, v in sorted(by_kind.items())},
        "stamp_latency_ms": _stats(stamp_lat),
        "stamp_latency_ms_by_kind": {k: _stats(v) for k, v in sorted(stamp_by_kind.items())},
        "detection_ms": _stats(detection),
        # the same with and without the CPU burners (normal priority, like the suite's processes)
        "detection_ms_burners": _stats([d for o, d in zip(arrived, detection) if o.event.burners]),
        "detection_ms_quiet": _stats([d for o, d in zip(arrived, detection) if not o.event.burners]),
    }


def _controller_rows(arrived):
    """:func:`score`'s latencies at the controller, the node that acts on the stop (a killed
    controller or simulator has none to act: the drives' watchdog brakes)."""
    acting = [o for o in arrived if controller_acts(o.event)]
    at_ctl = [o for o in acting if o.controller_ns]
    ctl_lat = [(o.controller_ns - o.latency_from()) * 1e-6 for o in at_ctl]
    ctl_det = [(o.controller_ns - o.evidence_from()) * 1e-6 for o in at_ctl]
    ctl_by_kind = {}
    for o, x in zip(at_ctl, ctl_lat):
        ctl_by_kind.setdefault(_kind_key(o.event), []).append(x)
    return {
        "controller_latency_ms": _stats(ctl_lat),
        "controller_latency_ms_by_kind": {k: _stats(v) for k, v in sorted(ctl_by_kind.items())},
        "controller_detection_ms": _stats(ctl_det),
        "controller_detection_ms_burners": _stats([d for o, d in zip(at_ctl, ctl_det) if o.event.burners]),
        "controller_detection_ms_quiet": _stats([d for o, d in zip(at_ctl, ctl_det) if not o.event.burners]),
        "controller_unmeasured": [o.event.label() for o in acting if not o.controller_ns],
    }


def _braking_rows(stopped):
    """:func:`score`'s wall latency of killed processes and the braking after each stop."""
    wall = [o.wall_latency_s * 1e3 for o in stopped if o.event.kind == "kill" and o.wall_latency_s is not None]
    # braking after the stop's arrival at the controller: every stop but a killed process'
    # (after a SIGKILL the other participants' sends to its shared-memory ports can block for
    # seconds, docs/reliability.md; a killed controller cannot brake, the drives' watchdog does)
    braking = [o.braking_ticks for o in stopped if o.braking_ticks is not None and o.event.kind != "kill"]
    braking_killed = [o.braking_ticks for o in stopped if o.braking_ticks is not None and o.event.kind == "kill"]
    return {
        "wall_latency_ms_killed": _stats(wall),
        "braking_ticks_max": max(braking) if braking else None,
        "braking_measured": len(braking),
        "braking_ticks_killed": _stats(braking_killed),
        "unbraked": [o.event.label() for o in stopped if o.braking_ticks is None and o.event.kind != "kill"],
    }


def _rest_rows(outcomes):
    """:func:`score`'s judgement of each stop's effect (:func:`judge_rest`)."""
    judged = [o for o in outcomes if o.stops and o.rest is not None and o.rest["ok"] is not None]
    not_at_rest = [{"event": o.event.label(), "fault_ns": o.fault_ns, "rest": o.rest, "bag": o.bag}
                   for o in judged if not o.rest["ok"]]
    rest_s = [o.rest["rest_s"] for o in judged if o.rest.get("rest_s") is not None]
    travel = [o.rest["travel_rad"] for o in judged if o.rest.get("travel_rad") is not None]
    return {
        "rest_judged": len(judged),
        "at_rest": len(judged) - len(not_at_rest),
        "rest_s_max": max(rest_s) if rest_s else None,
        "travel_rad_max": max(travel) if travel else None,
        "not_at_rest": not_at_rest,
    }


def _step_rows(outcomes):
    """:func:`score`'s recovery stops and the simulator's stale and ahead-of-monitor steps."""
    return {
        "recovery_stops": sum(o.recovery_stops for o in outcomes),
        "stale_steps": sum(o.stale_steps for o in outcomes),
        "stale_steps_burners": sum(o.stale_steps for o in outcomes if o.event.burners),
        "stale_steps_by_event": {k: v for k, v in _steps_by_event(outcomes, "stale_steps").items() if v},
        "ahead_steps": sum(o.ahead_steps for o in outcomes),
        "ahead_steps_by_event": {k: v for k, v in _steps_by_event(outcomes, "ahead_steps").items() if v},
    }


def controller_acts(event):
    """Whether the controller that had the stop is the one that acts on it: not after its own
    or the simulator's SIGKILL (the drives' watchdog brakes; a restarted controller's first
    command is its start, not the stop's arrival)."""
    return not (event.kind == "kill" and event.target in ("controller_node", "sim_node"))


def _kind_key(event):
    """The row an event's latency goes to: the simulator fault, ``link <fault>``, or the kind."""
    return (event.fault if event.kind == "sim" else
            f"link {event.fault}" if event.kind == "link" else event.kind)


def _steps_by_event(outcomes, attr):
    """A simulator step count (``stale_steps``, ``ahead_steps``) summed by event kind and target."""
    out = {}
    for o in outcomes:
        key = o.event.label().split(" ")[0] + (" " + o.event.target if o.event.target else "")
        out[key] = out.get(key, 0) + getattr(o, attr)
    return out


def _f(x):
    return "-" if x is None else f"{x:.3g}"


def table(s):
    """The score as one Markdown table (rows: the measures; the misses and false stops after it)."""
    def ms(st):
        if not st or not st["n"]:
            return "-"
        return f"{st['p50']:.1f} / {st['p99']:.1f} / {st['max']:.1f} (n={st['n']})"
    rows = [
        ("events (faults expecting a stop)", f"{s['events']} ({s['faults_injected']})"),
        ("stops / missed stops", f"{s['stops']} / {s['missed_stops']}"),
        ("frozen sensors whose joint did not move (unobservable, not scored)", str(len(s.get("unobservable", [])))),
        ("frozen sensors stopped before their joint moved at > 0.05 rad/s (stops; ms after the fault)",
         f"{len(s.get('stopped_before_motion', []))}" + (" (" + ", ".join(
             f"{x['latency_ms']:.0f}" for x in s.get("stopped_before_motion", [])) + ")"
             if s.get("stopped_before_motion") else "")),
        ("false stops", str(s["false_stops"])),
        ("freezes in the tolerance band (stopped)", f"{s['either']['events']} ({s['either']['stopped']})"),
        ("fault-free monitored time, simulated min", f"{s['fault_free_minutes']:.2f}"),
        ("events with CPU burners on", str(s["burner_events"])),
        ("stop latency from the fault's stamp, ms (p50 / p99 / max)", ms(s["latency_ms"])),
        ("the stop's own stamp after the fault's, ms", ms(s["stamp_latency_ms"])),
        ("the stop's arrival after the later of its own stamp and the fault's (detection and "
         "delivery), ms", ms(s.get("detection_ms"))),
        ("  ... with the CPU burners on / off, ms", f"{ms(s.get('detection_ms_burners'))} / "
                                                  f"{ms(s.get('detection_ms_quiet'))}"),
        ("the stop's arrival at the controller after the fault's stamp (upper bound: its first "
         "braking measurement), ms", ms(s.get("controller_latency_ms"))),
        ("  ... after the later of its own stamp and the fault's, burners on / off, ms",
         f"{ms(s.get('controller_detection_ms_burners'))} / {ms(s.get('controller_detection_ms_quiet'))}"),
        ("  stops without a braking command in the bag (killed controller / simulator apart)",
         str(len(s.get("controller_unmeasured", [])))),
        ("killed process: wall time to the stop, ms", ms(s["wall_latency_ms_killed"])),
        ("braking onset after the stop's arrival, ticks (max; killed processes apart)",
         "-" if s["braking_ticks_max"] is None else f"{s['braking_ticks_max']:g} (n={s['braking_measured']})"),
        ("  after a killed observer or simulator, ticks (p50 / p99 / max)", ms(s["braking_ticks_killed"])),
    ]
    rows.append(("stops judged from the bag: at rest / judged (slowest rest, s; largest travel, rad)",
                 f"{s['at_rest']} / {s['rest_judged']} ({_f(s['rest_s_max'])}; {_f(s['travel_rad_max'])})"))
    rows.append(("simulator steps on a stale command (with burners on)",
                 f"{s['stale_steps']} ({s['stale_steps_burners']}); by event: {s['stale_steps_by_event']}"))
    rows.append(("simulator steps ahead of the monitor's verdicts (the monitor silent for the lockstep timeout)",
                 f"{s['ahead_steps']}; by event: {s['ahead_steps_by_event']}"))
    rows += [(f"  latency, {k}", ms(v)) for k, v in s["latency_ms_by_kind"].items()]
    rows += [(f"  own stamp after the fault's, {k}", ms(v))
             for k, v in s.get("stamp_latency_ms_by_kind", {}).items()]
    rows += [(f"  arrival at the controller, {k}", ms(v))
             for k, v in s.get("controller_latency_ms_by_kind", {}).items()]
    out = ["| measure | value |", "|---|---|"] + [f"| {a} | {b} |" for a, b in rows]
    if s.get("apparatus_stops"):
        out.append(f"\nstops while the campaign's recorder switched bags (apparatus, not scored): "
                   f"{len(s['apparatus_stops'])}: "
                   + "; ".join(f"{a[2][:120]} in {a[3]}" for a in s["apparatus_stops"]))
    for m in s["misses"]:
        out.append(f"\nmissed: {m['event']} (fault stamp {m['fault_ns']}; {m['note']}) in {m['bag']}")
    for m in s["not_at_rest"]:
        out.append(f"\nnot at rest: {m['event']} (fault stamp {m['fault_ns']}): {m['rest']} in {m['bag']}")
    for m in s["unbraked"]:
        out.append(f"\nno braking command after the stop: {m}")
    for f in s["false"]:
        out.append(f"\nfalse stop: {f['where']} {f['event']}: {f['stop']} in {f['bag']}")
    return "\n".join(out)
