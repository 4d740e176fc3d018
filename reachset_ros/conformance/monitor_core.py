"""The monitor node without ROS: pairing, fault detection and the monitor (:class:`MonitorCore`).

``/joint_states`` (y = position) and ``/plant_input`` (u_p) are paired by header stamp and
joint name and fed to :class:`~reachset_ros.conformance.monitor.Monitor` one tick at a time;
bad input becomes a :class:`~reachset_ros.conformance.watches.FaultEvent`, a processed tick a
:class:`~reachset_ros.conformance.watches.TickEvent`. :mod:`reachset_ros.nodes.monitor_node`
is its ROS adapter (topics, the safe stop, the window bag, the watchdog, diagnostics).
"""
from __future__ import annotations

import collections
import time

import numpy as np

from ..errors import ReachsetError
from .envelope import EnvelopeTracker
from .model import ConformanceModel
from .monitor import Monitor, MonitorModel
from .watches import CoverageWatch, FaultEvent, StuckSensorWatch, TickEvent


#: the topic of each half of a tick (``kind`` "y" or "u"), as the faults' reasons name it
TOPIC = {"y": "/joint_states", "u": "/plant_input"}


class MonitorCore:
    """Pairing, fault detection and the monitor, without ROS (so it is testable and reusable).

    ``add_y``/``add_u`` take (stamp, names, values); completed ticks are processed in stamp
    order and returned as a list of events: a :class:`~reachset_ros.conformance.watches.TickEvent`
    per processed tick (its ``result`` is :meth:`Monitor.tick`'s dict; ``conformant`` only if
    every joint checked a test case and none was violated) or a
    :class:`~reachset_ros.conformance.watches.FaultEvent` (``kind``, ``reason``, ``joint``).

    What each kind of bad input becomes (docs/reliability.md, "Nodes"):

    * a message lacking a monitored joint, or naming one twice: fault ``name_mismatch``;
      names that are not monitored are ignored (counted in ``extra_names_y|u``);
    * a message whose value array is not as long as its name array: fault ``invalid_sample``;
      a non-finite value of a monitored joint (the monitor's ``invalid`` status): the same;
    * a stamp lower than the previous one on the same topic (the source's clock went back, or
      two publishers share the topic): fault ``stamp_backwards``; an equal stamp (a repeated
      message) is skipped and counted (``duplicate_y|u``), as is a message for a tick that
      was already processed (``stale_y|u``);
    * a tick whose other half never comes: dropped when a later tick completes or when more
      than ``max_pending`` ticks wait (``dropped_incomplete``); missing ticks end the test
      cases (as ``reachset check`` never lets a test case span a gap): ``gaps`` counts the
      gaps and ``missing_ticks`` the ticks missing in them. Long silence is the node's
      watchdog's business;
    * a stream on which the test cases the model needs cannot be formed (its period is not
      the model's dt, or losses keep every test case short of k*): fault ``coverage`` from
      :class:`~reachset_ros.conformance.watches.CoverageWatch`, within ``max_missing_ticks``
      ticks after the warm-up; ``unchecked_ticks`` counts ticks at which some joint checked
      nothing, ``short_ticks`` those at which something but not step k* was checked; samples
      lost again within ``gap_window`` ticks of the previous loss: the same fault at once;
    * a joint's position reading repeated ``stuck_ticks`` times while its reference (fed by
      :meth:`add_reference`) moves at >= ``stuck_speed``: fault ``invalid_sample`` (a stuck
      sensor, :class:`~reachset_ros.conformance.watches.StuckSensorWatch`).
    """

    #: defaults of the stuck-sensor rule (:class:`~reachset_ros.conformance.watches.StuckSensorWatch`)
    #: and of the lossy-link rule (``gap_window`` of
    #: :class:`~reachset_ros.conformance.watches.CoverageWatch`), the node's parameters' defaults
    STUCK_TICKS, STUCK_SPEED, GAP_WINDOW = 5, 0.05, 25

    def __init__(self, model: ConformanceModel, joints=None, max_missing_ticks=25, effort=None,
                 stuck_ticks=STUCK_TICKS, stuck_speed=STUCK_SPEED, gap_window=GAP_WINDOW):
        self.model = model
        #: ``input_source: effort``: the plant input of each /joint_states message is computed
        #: from its position, velocity and effort (:class:`~reachset_ros.robot.effort.EffortInput`,
        #: used through its ``joint_names``, ``model``, ``plant_inputs`` and ``plant_input``: no import of robot)
        self.effort = effort
        self._effort_data = None if effort is None else effort.model.pin_model.createData()
        self._effort_map = (None, None)
        self._effort_names = None if effort is None else list(effort.joint_names)
        self.joints = list(joints or model.joints)
        if len(set(self.joints)) != len(self.joints):
            raise ReachsetError(f"joints {self.joints} name a joint twice")
        missing = [j for j in self.joints if j not in model.joints]
        if missing:
            raise ReachsetError(f"joint {missing[0]} is not in the model")
        thm = model.theorem1()
        self.monitor = Monitor([MonitorModel.from_model(model, j, thm) for j in self.joints])
        self.wanted = set(self.joints)
        self.dt_ns = int(round(model.plant.dt * 1e9))
        self.pending = collections.OrderedDict()
        # ticks waiting for their other half: a stalled controller may lag by many ticks
        self.max_pending = 2 * (model.horizon + 1)
        self.last_stamp = None
        self.topic_last = {}
        self.counters = collections.Counter()
        self.ticks_since_reset = 0
        keep = model.horizon + model.estimator.history + 2
        self.window = collections.deque(maxlen=keep)
        self.coverage = CoverageWatch(self.dt_ns, model.estimator.history, model.horizon, max_missing_ticks,
                                      gap_window)
        self.set_stuck_rule(stuck_ticks, stuck_speed)
        self._name_map = {}           # topic kind -> (names, index array or None, other names present)
        self._ref_map = None          # /reference names -> (names, index array or None if a joint lacks)
        #: the validated envelope's online classification (issue 37; None: the model records none for these joints)
        env = model.envelope
        self.envelope = EnvelopeTracker(env, self.joints) if env is not None and self.wanted <= set(env.joints) \
            else None

    def set_stuck_rule(self, ticks, speed):
        """The stuck-sensor rule anew (``self.stuck``, fed by :meth:`add_reference`; None: off,
        ``ticks`` 0): at start and when the node's ``stuck_ticks``/``stuck_speed`` change."""
        self.stuck = StuckSensorWatch(self.joints, self.dt_ns, ticks, speed) if int(ticks) > 0 else None

    def reset(self):
        """Forget test cases, waiting ticks and stamps (the reset service); keep the counters."""
        self.monitor.reset()
        self.coverage.reset()
        if self.envelope is not None:
            self.envelope.reset()
        if self.stuck is not None:
            self.stuck.reset()
        self.ticks_since_reset = 0
        self.pending.clear()
        self.last_stamp = None
        self.topic_last.clear()

    def add_y(self, stamp, names, values):
        return self.add("y", stamp, names, values)

    def add_joint_state(self, stamp, names, position, velocity=(), effort=()):
        """One JointState message: its position is y; with an effort source also u_p of the
        same tick, ``M̂(q)⁻¹ (s τ − ψ̂(q, q̇))`` (:func:`reachset_ros.robot.effort.plant_inputs`,
        the function ``reachset check|replay --input effort`` applies to a bag, so the two
        agree to the bit). A message that lacks a joint of the robot model is a
        ``name_mismatch`` fault; a missing or short velocity/effort array, or a non-finite
        value, gives a non-finite u_p: an ``invalid_sample`` fault."""
        events = self.add("y", stamp, names, position)
        if self.effort is None:
            return events
        robot = self.effort.joint_names
        names = list(names)
        if self._effort_map[0] != names:
            pos = {n: i for i, n in enumerate(names)}
            missing = [j for j in robot if j not in pos]
            if missing:
                self.counters["rejected_u"] += 1
                return events + [FaultEvent(stamp, "name_mismatch", f"/joint_states at {stamp} ns lacks joint "
                                            f"{missing[0]} of the robot model (input_source effort)", missing[0])]
            self._effort_map = (names, np.array([pos[j] for j in robot], dtype=np.intp))
        idx = self._effort_map[1]
        n = len(names)
        if len(position) == len(velocity) == len(effort) == n:
            # one row of plant_inputs (the same operations, so the same bits), without its 2-D detour
            u = self.effort.plant_input(*(np.asarray(a, dtype=np.float64)[idx] for a in (position, velocity, effort)),
                                        data=self._effort_data)
        else:
            arrs = []
            for a in (position, velocity, effort):
                a = np.asarray(a, dtype=np.float64)
                arrs.append(a[idx] if len(a) == n else np.full(len(robot), np.nan))
            u = self.effort.plant_inputs(arrs[0][None], arrs[1][None], arrs[2][None], self._effort_data)[0]
        return events + self.add("u", stamp, self._effort_names, u)

    def add_u(self, stamp, names, values):
        return self.add("u", stamp, names, values)

    def add_reference(self, stamp, names, velocity):
        """A ``/reference`` sample for the stuck-sensor rule: its stamp and the joints' qd_d.

        Returns nothing: the rule is applied at the ticks (:meth:`_process`). A reference
        that lacks a monitored joint or whose velocity array is short is not used (counted
        in ``unusable_reference``): the rule then checks nothing at those ticks, and the
        sets' check goes on as before."""
        if self.stuck is None:
            return
        names = list(names)
        cached = self._ref_map
        if cached is None or cached[0] != names:
            pos = {n: i for i, n in enumerate(names)}
            idx = None if any(j not in pos for j in self.joints) else np.array([pos[j] for j in self.joints])
            cached = self._ref_map = (names, idx)
        if cached[1] is None or len(velocity) != len(names):
            self.counters["unusable_reference"] += 1
            return
        self.stuck.add_reference(stamp, np.asarray(velocity, dtype=np.float64)[cached[1]])

    def _pick(self, kind, names, values, stamp):
        """The monitored joints' values in ``self.joints`` order, or None and the FaultEvent.

        The mapping from a message's names to the monitored joints is kept per topic while
        the names stay the same (the usual case: every message names the same joints in the
        same order); names that change are checked anew, a bad list is never kept.
        """
        if len(values) != len(names):
            return None, FaultEvent(stamp, "invalid_sample",
                                    f"{TOPIC[kind]} at {stamp} ns has {len(names)} names but {len(values)} values")
        cached = self._name_map.get(kind)
        if cached is None or cached[0] != names:
            idx, extra, err = self._map_names(kind, names, stamp)
            if err is not None:
                return None, err
            cached = self._name_map[kind] = (list(names), idx, extra)
        if cached[2]:
            self.counters["extra_names_" + kind] += 1
        vals = np.array(values, dtype=np.float64)
        return (vals if cached[1] is None else vals[cached[1]]), None

    def _map_names(self, kind, names, stamp):
        """(index array or None for the identity, whether other names are present, FaultEvent or None)."""
        what = TOPIC[kind]
        idx = {}
        for i, n in enumerate(names):
            if n in idx and n in self.wanted:
                return None, False, FaultEvent(stamp, "name_mismatch", f"{what} at {stamp} ns names joint {n} twice", n)
            idx[n] = i
        missing = [j for j in self.joints if j not in idx]
        if missing:
            return None, False, FaultEvent(stamp, "name_mismatch", f"{what} at {stamp} ns lacks joint {missing[0]}",
                                           missing[0])
        order = [idx[j] for j in self.joints]
        identity = order == list(range(len(names)))
        return (None if identity else np.array(order, dtype=np.intp)), len(idx) > len(self.joints), None

    def add(self, kind, stamp, names, values):
        events = []
        last = self.topic_last.get(kind)
        self.topic_last[kind] = stamp   # after a jump back, the new clock is the reference
        if last is not None and stamp < last:
            self.counters["stamp_backwards_" + kind] += 1
            return [FaultEvent(stamp, "stamp_backwards",
                               f"{TOPIC[kind]} stamp went backwards: {stamp} ns after {last} ns")]
        if last is not None and stamp == last:
            self.counters["duplicate_" + kind] += 1
            return events
        if self.last_stamp is not None and stamp <= self.last_stamp:
            self.counters["stale_" + kind] += 1
            return events
        vals, err = self._pick(kind, names, values, stamp)
        if err is not None:
            self.counters["rejected_" + kind] += 1
            return [err]
        if not np.isfinite(vals).all():
            bad = np.flatnonzero(~np.isfinite(vals))
            # at once, not when the tick's other half arrives: that half may never come (a
            # controller that gets no estimate for the sample commands nothing for its stamp)
            self.counters["invalid_" + kind] += 1
            j = self.joints[int(bad[0])]
            return [FaultEvent(stamp, "invalid_sample",
                               f"invalid (non-finite) sample of joint {j} at {stamp} ns on {TOPIC[kind]}", j)]
        entry = self.pending.setdefault(stamp, {})
        entry[kind] = vals
        if "y" in entry and "u" in entry:
            # older incomplete ticks can no longer be completed: they are missing data
            for s in [s for s in self.pending if s < stamp]:
                self.counters["dropped_incomplete"] += 1
                del self.pending[s]
            del self.pending[stamp]
            events += self._process(stamp, entry["y"], entry["u"])
        while len(self.pending) > self.max_pending:
            # the oldest stamp goes (not the oldest arrival: a late half of an old tick must
            # not push out a newer tick that can still be completed)
            del self.pending[min(self.pending)]
            self.counters["dropped_incomplete"] += 1
        return events

    def _process(self, stamp, y, u):
        if self.last_stamp is not None:
            step = stamp - self.last_stamp
            if not (0.5 * self.dt_ns <= step <= 1.5 * self.dt_ns):   # the monitor's gap rule
                self.counters["gaps"] += 1
                self.counters["missing_ticks"] += max(0, int(round(step / self.dt_ns)) - 1)
        self.last_stamp = stamp
        self.window.append((stamp, y, u))
        t0 = time.perf_counter()
        res = self.monitor.tick(stamp, y, u)
        duration = time.perf_counter() - t0
        self.counters["ticks"] += 1
        self.ticks_since_reset += 1
        if "invalid" in res["status"]:
            self.counters["invalid_ticks"] += 1
            j = self.joints[res["status"].index("invalid")]
            return [FaultEvent(stamp, "invalid_sample", f"invalid (non-finite) sample of joint {j} at {stamp} ns", j)]
        longest = min(res["longest"].tolist())
        if longest < self.monitor.horizon:
            self.counters["unchecked_ticks" if longest < 0 else "short_ticks"] += 1
        outside = None
        if self.envelope is not None:              # the law replay and check were tested with
            outside = tuple(bool(x) for x in self.envelope.tick(stamp, y, u))
            self.counters["outside_envelope_ticks"] += any(outside)
        events = [TickEvent(stamp, res, duration, longest, outside)]
        fault = self.coverage.update(stamp, longest)
        if fault is not None:
            self.counters["coverage_faults"] += 1
            events.append(fault)
        if self.stuck is not None:
            fault = self.stuck.update(stamp, y)
            if fault is not None:
                self.counters["stuck_sensor"] += 1
                events.append(fault)
        return events
