"""Minimum detectable fault (issue 35.5): the smallest fault the monitor stops within 100 ms.

Pure core, no DDS. One case is the nodes' code path in one loop: the simulated arm
(:mod:`.simulator`, with a fault of :data:`FAULT_CLASSES` injected at ``Setup.onset_s``) in
closed loop with the certified control law (:func:`.recordings.simulate_arm_recordings`, each
joint's observer and :class:`~reachset_ros.systems.closedloop.FeedbackLaw`, the nominal
feedback linearization), and its ``/joint_states``, ``/plant_input`` and ``/reference``
samples fed tick by tick to the monitor node's core
(:class:`~reachset_ros.conformance.monitor_core.MonitorCore`) with a given model. A case is
*stopped* at the stamp of the first tick the monitor would stop on: a measurement outside
the model's reachable set (``violation``) or a data fault of the core (``invalid_sample``, a
stuck sensor, ...); :func:`run_case`.

:func:`minimum_detectable` bisects the magnitude (:func:`bisect`) for the smallest one
stopped within ``Setup.within_s`` (100 ms) of the fault's onset stamp (the first measurement
the fault can change, :meth:`~.simulator.SimulatedArm.onset_stamp`) in every seed; detection
is assumed monotone in the magnitude (a larger fault of the same kind leaves the sets no
later), which the bisection's bracket reports but does not prove.

The yardstick (``/work/shared/notes/detection-limit.md``; docs/performance.md, "Minimum
detectable fault"): no sound monitor can guarantee to stop a fault that the true
disturbances can mimic. In simulation the truth is known: :func:`disturbance_trace` recovers
the per-tick disturbance of the paper's Appendix-A plant, ``w = [w1, w2]`` (velocity and
acceleration generators of ``G'_W``), from the arm's true states and the plant input that
acted, and :func:`limits` turns a fault-free run's traces into each class' limit:

* ``acceleration`` (rad/s^2 on one joint): ``max |w2|`` of that joint: a constant
  acceleration no larger is the disturbance at its bound;
* ``torque`` (N m on one joint): the largest torque whose acceleration on every joint ``i``,
  ``|M_true(q)^-1_ij| tau`` along the run, stays within joint i's ``max |w2|``;
* ``bias`` (rad on one joint's position reading): four times the measurement-noise bound
  ``n`` (3 sigma, the simulator's clip, plus half the encoder step), :func:`bias_limits`. The
  true position is known only through the readings, so a healthy arm standing ``b/2`` off
  the faulty arm's position, with the same velocity, inputs and disturbances, reads the same
  as the arm with a bias ``b <= 4 n`` whenever the noise sits at ``b/2 - n .. n`` before the
  step and ``-n .. n - b/2`` after it: every sample's error within ``n``, on both sides,
  forever (:func:`bias_twin`). Before 2026-12-01 the limit was ``2 n`` (a noise sample moving
  from one end of V to the other), which holds the true position known; :func:`bias_limits`
  also gives the limit on the simulator's quantised sensor itself, ``2 q floor(6 sigma / q)``
  (q the encoder step), for every trajectory.

Frozen sensors and NaN samples have no magnitude: the stuck-sensor rule and the
non-finite-sample rule bound them (reported by the benchmark with their latency).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .. import defaults
from .. import robot as rb
from ..conformance import model as mdl
from ..conformance.estimators import Estimator
from ..conformance.identify import identify_sets
from ..conformance.monitor_core import MonitorCore
from ..conformance.theorem1 import Theorem1, deviation_extremes_many
from ..conformance import validation as _validation  # noqa: F401  (registers detection.within_s)
from ..conformance.watches import FaultEvent
from ..errors import ReachsetError
from ..systems.plant import lwa4p_joint_plant
from . import simulator as simm
from .recordings import recordings_series, simulate_arm_recordings

__all__ = ["FAULT_CLASSES", "WITHIN_S", "Setup", "Case", "Bracket", "make_fault", "simulate", "monitor_stops",
           "run_case", "detected", "bisect", "minimum_detectable", "disturbance_trace", "limits", "bias_limits",
           "bias_twin", "sets_limit",
           "fault_free", "training_series",
           "identify_model"]

#: the fault classes with a magnitude, per joint (the simulator's faults; units rad/s^2, N m, rad)
FAULT_CLASSES = ("acceleration", "torque", "bias")
#: a fault counts as stopped when the monitor's stop stamp is at most this after its onset (s):
#: the registered ``detection.within_s``
WITHIN_S = defaults.get("detection.within_s")


def make_fault(kind, joint, magnitude, start_s):
    """The simulator's fault of ``kind`` (as ``sim_node``'s ``fault`` parameter names them)."""
    if kind == "acceleration":
        return simm.AccelerationDisturbance(start_s=start_s, joint=joint, acceleration=float(magnitude))
    if kind == "torque":
        return simm.TorqueDisturbance(start_s=start_s, joint=joint, torque=float(magnitude))
    if kind == "bias":
        return simm.SensorBias(start_s=start_s, joint=joint, bias=float(magnitude))
    if kind == "frozen":
        return simm.FrozenSensor(start_s=start_s, joint=joint)
    if kind == "nan":
        return simm.NaNSamples(start_s=start_s, joint=joint, count=max(1, int(magnitude)))
    raise ReachsetError(f"unknown fault {kind!r}; known: {', '.join(FAULT_CLASSES + ('frozen', 'nan'))}")


@dataclass(frozen=True, kw_only=True)
class Setup:
    """The simulated set-up of every case.

    Attributes
    ----------
    sim_config : SimConfig or None
        The arm (None: :meth:`~.simulator.SimConfig.calibrated`, the simulated LWA-4P).
    gains : dict or None
        Observer and control-law gains (None: the simulator's recording gains).
    reference_config : ReferenceConfig or None
        The random point-to-point references (None: Table I's).
    onset_s : float
        When the fault starts, s after the reset (the monitor's test cases have reached k*).
    within_s : float
        The detection window after the onset (:data:`WITHIN_S`).
    tail_s : float
        Simulated beyond the window (the last ticks of the window complete).
    """

    sim_config: object = None
    gains: dict | None = None
    reference_config: object = None
    onset_s: float = 3.0
    within_s: float = WITHIN_S
    tail_s: float = 0.02

    def config(self):
        return self.sim_config if self.sim_config is not None else simm.SimConfig.calibrated()

    @property
    def seconds(self):
        return self.onset_s + self.within_s + self.tail_s


@dataclass(frozen=True, kw_only=True)
class Case:
    """One simulated case: what the monitor did around one fault.

    ``stop_ns``/``stop_kind``/``stop_joint``: the first stop at or after the onset (None, ""
    if none in the run); ``false_stops``: stop ticks before the onset (fault-free running).
    """

    fault: str
    joint: str
    magnitude: float
    seed: int
    onset_ns: int
    stop_ns: int | None
    stop_kind: str
    stop_joint: str
    false_stops: int

    @property
    def latency_ms(self):
        """Onset to the stop's stamp (the first non-conformant measurement), ms; None: no stop."""
        return None if self.stop_ns is None else (self.stop_ns - self.onset_ns) * 1e-6

    def stopped_within(self, seconds):
        return self.stop_ns is not None and self.stop_ns - self.onset_ns <= round(seconds * 1e9)


def simulate(setup: Setup, *, seed, faults=(), seconds=None):
    """``(recordings, log)`` of :func:`~.recordings.simulate_arm_recordings` for ``setup``."""
    log = {}
    recs = simulate_arm_recordings(setup.seconds if seconds is None else seconds, setup.gains, seed=seed,
                                   sim_config=setup.config(), reference_config=setup.reference_config,
                                   faults=tuple(faults), log=log)
    return recs, log


def monitor_stops(model, recs, *, after_ns=None):
    """The ticks the monitor core stops on, fed as the nodes feed it (reference, position, input).

    Returns a list of ``(stamp_ns, kind, joint)``: ``violation`` (a measurement outside the
    reachable set; the first violated joint) or a :class:`FaultEvent`'s kind. With
    ``after_ns`` the feed ends at the first stop at or after that stamp.
    """
    names = list(recs)
    first = recs[names[0]]
    Y = np.column_stack([recs[n].y for n in names])
    U = np.column_stack([recs[n].u for n in names])
    QD = np.column_stack([recs[n].qd_d for n in names])
    core = MonitorCore(model, [n for n in names if n in model.joints])
    out = []
    for k, st in enumerate(first.stamps.tolist()):
        core.add_reference(st, names, QD[k])
        events = core.add_y(st, names, Y[k]) + core.add_u(st, names, U[k])
        for ev in events:
            if isinstance(ev, FaultEvent):
                out.append((int(ev.stamp), ev.kind, ev.joint or ""))
            elif "violation" in ev.result["status"]:
                out.append((int(ev.stamp), "violation", core.joints[ev.result["status"].index("violation")]))
        if after_ns is not None and out and out[-1][0] >= after_ns:
            break
    return out


def run_case(model, setup: Setup, *, fault, joint, magnitude, seed):
    """One case: the fault (``magnitude`` 0 of a physical fault: none at all) and the monitor."""
    faults = [] if (magnitude == 0 and fault in FAULT_CLASSES) else [make_fault(fault, joint, magnitude,
                                                                               setup.onset_s)]
    recs, log = simulate(setup, seed=seed, faults=faults)
    stamps = log["stamps"]
    onset = int(log["fault_onsets"][0]) if faults else int(stamps[0] + round(setup.onset_s * 1e9))
    stops = monitor_stops(model, recs, after_ns=onset)
    after = [s for s in stops if s[0] >= onset]
    st = after[0] if after else (None, "", "")
    return Case(fault=fault, joint=joint, magnitude=float(magnitude), seed=int(seed), onset_ns=onset,
                stop_ns=st[0], stop_kind=st[1], stop_joint=st[2], false_stops=len(stops) - len(after))


def detected(model, setup: Setup, *, fault, joint, magnitude, seeds):
    """``(all stopped within the window, cases)`` over ``seeds``; stops at the first seed that
    is not (the rest would not change the verdict)."""
    cases = []
    for s in seeds:
        c = run_case(model, setup, fault=fault, joint=joint, magnitude=magnitude, seed=s)
        cases.append(c)
        if not c.stopped_within(setup.within_s):
            return False, cases
    return True, cases


@dataclass(frozen=True, kw_only=True)
class Bracket:
    """The result of :func:`bisect`: ``lo`` not detected, ``hi`` detected (None: nothing tried
    up to the largest magnitude was), and every magnitude tried with its verdict."""

    lo: float
    hi: float | None
    tried: tuple

    @property
    def width(self):
        return None if self.hi is None else self.hi - self.lo


def bisect(predicate, *, lo, hi, rel_tol=0.05, grow=2.0, max_grow=4, max_steps=40):
    """Bracket the smallest magnitude for which ``predicate`` holds (assumed monotone).

    ``predicate(lo)`` must be false (0: no fault); ``hi`` is grown by ``grow`` up to
    ``max_grow`` times until the predicate holds. Then the bracket is halved (arithmetic
    while ``lo`` is 0, geometric after) until ``hi <= lo * (1 + rel_tol)``.

    Returns
    -------
    Bracket
    """
    if not (0 <= lo < hi):
        raise ReachsetError(f"bisect: need 0 <= lo < hi, got {lo}, {hi}")
    tried = []

    def ask(x):
        v = bool(predicate(x))
        tried.append((float(x), v))
        return v

    if ask(lo):
        raise ReachsetError(f"bisect: the predicate already holds at the lower end {lo}")
    for _ in range(max_grow + 1):
        if ask(hi):
            break
        lo, hi = hi, hi * grow
    else:
        return Bracket(lo=lo, hi=None, tried=tuple(tried))
    for _ in range(max_steps):
        if lo > 0 and hi <= lo * (1 + rel_tol):
            break
        mid = 0.5 * (lo + hi) if lo <= 0 or hi > 4 * lo else math.sqrt(lo * hi)
        if ask(mid):
            hi = mid
        else:
            lo = mid
    return Bracket(lo=lo, hi=hi, tried=tuple(tried))


def minimum_detectable(model, setup: Setup, *, fault, joint, seeds, hi, rel_tol=0.05):
    """The bracketed minimum magnitude of ``fault`` on ``joint`` stopped within the window in
    every seed, and the cases at the bracket's upper end (their latencies).

    Returns a dict: ``lo``, ``hi`` (:class:`Bracket`), ``latency_ms`` (per seed, at ``hi``),
    ``tried`` (magnitude, verdict), ``cases`` (cases run) and ``false_stops`` (stop ticks in
    the fault-free stretch before the onset, summed over every case run)."""
    ran = {}

    def pred(m):
        if m <= 0:
            return False
        ok, ran[m] = detected(model, setup, fault=fault, joint=joint, magnitude=m, seeds=seeds)
        return ok
    br = bisect(pred, lo=0.0, hi=hi, rel_tol=rel_tol)
    cases = [c for cs in ran.values() for c in cs]
    lat = None if br.hi is None else [c.latency_ms for c in ran[br.hi]]
    return {"fault": fault, "joint": joint, "lo": br.lo, "hi": br.hi, "latency_ms": lat, "tried": list(br.tried),
            "cases": len(cases), "false_stops": sum(c.false_stops for c in cases)}


def disturbance_trace(log, dt=simm.DT):
    """Per-tick disturbances ``(w1, w2)`` (T-2, n) of the Appendix-A plant along a run.

    ``q[k+1] = q[k] + dt qd[k] + dt^2/2 (u + w2) + dt w1``, ``qd[k+1] = qd[k] + dt (u + w2)``
    with ``u`` the plant input acting during ``[t_k, t_{k+1})`` (computed at tick k-1: one
    sample of input delay) and ``q``, ``qd`` the arm's true states (``log["q_true"]``,
    ``log["qd_true"]``); ``log["u"]`` (T, n) the plant inputs of the run."""
    q, qd, u = (np.asarray(log[k], float) for k in ("q_true", "qd_true", "u"))
    ua = u[:-2]                                   # acting during [t_k, t_{k+1}), k = 1..T-2
    w2 = (qd[2:] - qd[1:-1]) / dt - ua
    w1 = (q[2:] - q[1:-1] - dt * qd[1:-1] - 0.5 * dt * dt * (ua + w2)) / dt
    return w1, w2


def _position_sigma(cfg, n):
    """The position noise's sigma per joint (``cfg.position_noise``: one value or n)."""
    return np.broadcast_to(np.asarray(cfg.position_noise, float), (n,))


def _noise_bound(cfg, n):
    return 3.0 * _position_sigma(cfg, n) + 0.5 * float(cfg.quantization)


def _twin_steps(sigma, q):
    """``M = floor(6 sigma / q)``: the encoder steps two readings' noises (each within
    +-3 sigma) can absorb between them; the quantised bias twin stands ``M q`` off."""
    return np.floor(6.0 * np.asarray(sigma, float) / q)


def bias_limits(cfg, n):
    """The largest sensor bias no sound monitor can promise to stop, per joint, two ways.

    Syntax: ``set_based, quantised = bias_limits(cfg, n)``.

    Parameters
    ----------
    cfg : SimConfig
        The simulator's configuration: ``position_noise`` sigma (per joint or one value),
        clipped at +-3 sigma, and ``quantization`` q, the encoder step the reading is rounded
        to before the noise is added (:meth:`.simulator.SimulatedArm._measure`).
    n : int
        The number of joints.

    Returns
    -------
    set_based : ndarray (n,)
        ``4 nb`` with ``nb = 3 sigma + q/2`` the bound of a reading's error: the limit when
        the noise is any sequence within ``[-nb, nb]``, as the acceleration class' limit takes
        the disturbance as any sequence within its bound (detection-limit note).
    quantised : ndarray (n,)
        ``2 q floor(6 sigma / q)`` (``12 sigma`` for q = 0): the limit on the simulator's own
        sensor, rounding included, along every trajectory. With the offset ``d = M q``
        (``M = floor(6 sigma / q)``) the rounded readings differ by exactly ``M q`` before
        the step and by at most ``M q`` after it, for every bias up to ``2 M q``; each
        difference is split between the two noise samples (``-D/2``, ``+D/2``, within the
        clip).

    Notes
    -----
    A bias ``b`` added to the position reading from sample 0 on (``y = Q(p + b) + nu``,
    ``p`` the true position) and a healthy arm at ``p + d`` (``y' = Q(p + d) + nu'``) give
    the same readings when ``|nu|, |nu'|`` can absorb the difference; with the same velocity,
    inputs and disturbances everything else is the same too, since a constant position offset
    is an equilibrium of the Appendix-A plant's difference (``A [1, 1, 0, 0, 0] = [1, 1, 0,
    0, 0]``) and the controller reads the same samples. So no monitor that never stops a
    healthy arm can promise to stop such a bias, however late. The constructions are
    :func:`bias_twin`; ``test_detectability.py`` checks them on a simulated run. Both are
    lower bounds of the true limit (a healthy arm could also move within its disturbance
    bound); neither uses the disturbance.

    Assumption: the twin is exact for the Appendix-A plant, the model the monitor checks. On
    the simulated rigid-body arm the same torques at a configuration ``d`` away accelerate the
    arm slightly differently (the gradient of gravity and inertia over ``d``, 0.07-0.23 mrad
    here); the twin's disturbance carries that difference, which is assumed to stay within the
    truth's disturbance bound. That is not checked here."""
    sig = _position_sigma(cfg, n)
    q = float(cfg.quantization)
    set_based = 4.0 * _noise_bound(cfg, n)
    quantised = 2.0 * q * _twin_steps(sig, q) if q > 0 else 12.0 * sig
    return set_based, quantised


def bias_twin(p, bias, *, sigma, quantization, onset=0):
    """A healthy reading sequence equal to a biased one: the construction behind
    :func:`bias_limits`' quantised limit.

    Syntax: ``twin = bias_twin(p, b, sigma=s, quantization=q, onset=k0)``.

    Parameters
    ----------
    p : array_like (T,)
        One joint's true positions, sample by sample (e.g. a simulated run's ``q_true``).
    bias : float
        The bias, added to the reading from sample ``onset`` on, ``0 <= bias <= 2 M q``.
    sigma, quantization : float
        The noise's sigma (clipped at +-3 sigma) and the encoder step q (> 0).

    Returns
    -------
    dict
        ``offset`` (``d = M q``), ``y`` (the biased readings ``Q(p + b H) + nu``),
        ``y_twin`` (the healthy arm's at ``p + d``, ``Q(p + d) + nu'``), ``noise`` and
        ``noise_twin`` (``nu = -D/2``, ``nu' = D/2`` with ``D`` the rounded readings'
        difference, each within ``[-3 sigma, 3 sigma]``). ``y == y_twin`` to the rounding of
        one addition."""
    p = np.asarray(p, float)
    q = float(quantization)
    d = float(_twin_steps(sigma, q)) * q
    step = np.where(np.arange(len(p)) >= onset, float(bias), 0.0)
    qb, qd = simm.quantize(p + step, q), simm.quantize(p + d, q)
    half = 0.5 * (qb - qd)
    return {"offset": d, "y": qb - half, "y_twin": qd + half, "noise": -half, "noise_twin": half}


def limits(setup: Setup, *, seeds, seconds=None):
    """Each class' detection limit per joint from fault-free runs of ``setup`` (module docstring).

    Returns ``{"acceleration": {joint: rad/s^2}, "torque": {joint: N m}, "bias": {joint: rad},
    "bias_quantised": {joint: rad}, "w2_max": {joint: rad/s^2}}`` (the two bias limits:
    :func:`bias_limits`)."""
    cfg = setup.config()
    truth = cfg.true_robot()
    data = rb.create_data(truth)
    w2max, minv = None, None
    for s in seeds:
        recs, log = simulate(setup, seed=s, seconds=seconds)
        names = list(recs)
        log = dict(log, u=np.column_stack([recs[n].u for n in names]))
        _, w2 = disturbance_trace(log, cfg.dt)
        m = np.max(np.abs(w2), axis=0)
        w2max = m if w2max is None else np.maximum(w2max, m)
        # the largest |M^-1_ij| along the run (every 10th tick: M changes slowly)
        inv = np.max([np.abs(np.linalg.inv(rb.mass_matrix(truth, data, q))) for q in log["q_true"][::10]], axis=0)
        minv = inv if minv is None else np.maximum(minv, inv)
    n = len(names)
    torque = {nm: float(np.min(w2max / minv[:, j])) for j, nm in enumerate(names)}
    bias, bias_q = bias_limits(cfg, n)
    return {"acceleration": dict(zip(names, w2max.tolist())), "torque": torque,
            "bias": dict(zip(names, bias.tolist())), "bias_quantised": dict(zip(names, bias_q.tolist())),
            "w2_max": dict(zip(names, w2max.tolist()))}


def sets_limit(model, joint, *, fault="acceleration", within_s=WITHIN_S):
    """The smallest fault the model's own sets stop within ``within_s`` at best, or None.

    Theorem 1's bound ``d+_k`` (``d-_k`` for a negative effect;
    :meth:`~reachset_ros.conformance.theorem1.Theorem1.offsets`) against the fault's own
    effect ``r`` on the deviation y_a[k] of a test case, with no disturbance and no noise at
    all, over every test case that starts up to k* ticks before the fault or during it, and
    the steps k whose measurement comes within ``within_s`` of the first one the fault
    changes: ``min |d_k| / |r|``, what the sets' size alone gives away, whatever the
    disturbances do (a torque depends on the configuration: None).

    A test case that starts at sample s (the fault from sample 0 on) deviates by

        y_a[k] = C A^k (x[s] - x_hat[s]) + sum_{i<k} C A^(k-1-i) w[s+i] + v[s+k],

    and the initial-state estimator's error is linear in the samples it read,
    ``x[s] - x_hat[s] = sum_t Sw[t] w[s-h+t] + sum_t Sv[t] v[s-h+t]``
    (:func:`~reachset_ros.conformance.theorem1.initial_error_maps`). A constant
    ``acceleration`` is ``w = g`` per unit (``g`` the plant's acceleration generator, the last
    column of ``G'_W``), a ``bias`` a step ``v = 1`` per unit. A test case that starts on
    the fault mistakes part of it for motion: for ``fd`` a bias shows as a velocity of
    ``b / dt``, which grows with k. Before 2026-11-28 only the test case started just before
    the fault counted (for a bias ``r = 1``): on the campaign's models that gave 0.3-1.6 mrad
    where the monitor stopped biases of 0.29-0.46 mrad (docs/performance.md). An estimator that
    is not exact on noise-free model data has no such maps: then only the test cases that
    start before the fault count (an upper end)."""
    from ..conformance.monitor import MonitorModel
    from ..conformance.theorem1 import initial_error_maps
    if fault not in ("acceleration", "bias"):
        return None
    mm = MonitorModel.from_model(model, joint)
    dp, dm = mm.dp_vec, mm.dm_vec
    plant, est = model.plant, model.estimator
    A, C = np.asarray(plant.A), np.asarray(plant.C)
    n, K, h = A.shape[0], len(dp) - 1, int(est.history)
    try:
        Sw, Sv = initial_error_maps(plant, est)
    except ReachsetError:           # no linear error map: only the cases that start before the fault
        Sw = Sv = None
    CA = [C]                        # C A^k, k = 0..K
    for _ in range(K):
        CA.append(CA[-1] @ A)
    if fault == "bias":             # v[t] = 1 for t >= 0: the samples themselves change from sample 0 on
        g, first = None, 0
        est_maps = None if Sv is None else [S[:, 0] for S in Sv]           # h + 1 samples s-h..s
    else:                           # w[t] = g for t >= 0: y[i] changes from the first i with C A^(i-1) g != 0
        g = np.asarray(plant.Gw)[:, -1]
        first = 1 + next(i for i in range(K) if abs(float((CA[i] @ g)[0])) > 0)
        est_maps = None if Sw is None else [S @ g for S in Sw]             # h samples s-h..s-1
    span = first + int(round(within_s / plant.dt))   # the last sample index within the window
    best = math.inf
    last_start = span if est_maps is not None else -1
    for s in range(-K, last_start + 1):
        err = np.zeros(n)           # x[s] - x_hat[s]: the fault's samples the estimator read
        if est_maps is not None:
            for t, e in enumerate(est_maps):
                if s - h + t >= 0:
                    err = err + e
        drift = np.zeros(n)         # sum_{i<k} A^(k-1-i) w[s+i]
        for k in range(0, min(K, span - s) + 1):
            if k > 0 and g is not None:
                drift = A @ drift + (g if s + k - 1 >= 0 else 0.0)
            if s + k < 0:
                continue
            r = float((CA[k] @ err)[0] + (C @ drift)[0] + (1.0 if g is None else 0.0))
            if r > 0:
                best = min(best, float(dp[k]) / r)
            elif r < 0:
                best = min(best, float(dm[k]) / -r)
    return best if math.isfinite(best) else None


def fault_free(model, setup: Setup, *, seeds, seconds):
    """The other side: fault-free runs of ``setup`` (``seconds`` each); returns a dict with
    ``runs``, ``seconds``, ``stops`` (every stop tick, (seed, stamp, kind, joint))."""
    stops = []
    for s in seeds:
        recs, _ = simulate(setup, seed=s, seconds=seconds)
        stops += [(int(s), *x) for x in monitor_stops(model, recs)]
    return {"runs": len(seeds), "seconds": float(seconds) * len(seeds), "stops": stops}


def identify_model(series, *, horizon=125, inflation=0.0, estimator="fd"):
    """A model identified from ``series`` ({joint: JointSeries}, e.g. :func:`training_series`'s):
    Theorem 1, min ‖W‖ + ‖V‖ (``reachset identify``'s default) with a given inflation."""
    plant = lwa4p_joint_plant()
    est = Estimator.named(estimator, plant)
    thm = Theorem1.build(plant, horizon)
    devs = deviation_extremes_many(plant, est, series, horizon, thm)
    joints = {}
    for n, dev in devs.items():
        sets = identify_sets(plant, thm, dev)
        joints[n] = mdl.JointSets(alpha_w=tuple(sets.alpha_w.tolist()), alpha_v=tuple(sets.alpha_v.tolist()),
                                  c_w=tuple(sets.c_w.tolist()), c_v=tuple(sets.c_v.tolist()),
                                  test_cases=dev.test_cases, horizon=horizon)
    return mdl.ConformanceModel(plant=plant, plant_spec={"kind": "lwa4p_joint", "dt": plant.dt}, estimator=est,
                                horizon=horizon, joints=joints, inflation=float(inflation),
                                input_source=mdl.input_source_of(None))


def training_series(setup: Setup, *, seeds, seconds):
    """``{joint: JointSeries}`` of fault-free runs of ``setup``, one segment per seed."""
    from ..bags import concat_series
    parts, t0 = [], None
    for s in seeds:
        ser = recordings_series(simulate(setup, seed=s, seconds=seconds)[0])[0]
        first = int(next(iter(ser.values())).stamps[0])
        shift = 0 if t0 is None else t0 - first
        parts.append({n: replace(x, stamps=x.stamps + shift) for n, x in ser.items()})
        t0 = int(next(iter(parts[-1].values())).stamps[-1]) + 1_000_000_000
    return concat_series(parts, next(iter(parts[0].values())).dt)
