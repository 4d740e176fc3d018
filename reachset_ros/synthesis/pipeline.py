"""Data in, results out: synthesis from bags (``reachset synthesize``) and the iterative procedure.

:func:`synthesize_bags` reads bags (``/joint_states``, ``/plant_input`` and the optional
``/reference``, or a reference class instead: one of them is required), builds the per-joint
problems and runs a mode (:class:`BagSynthesis`, which
also makes the model file). :func:`iterate` is the paper's iterative procedure (Sec. III-D,
Fig. 4) around a user-given ``record(gains) -> data`` callable.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .. import conformance as cf
from .. import defaults
from .. import guarantees
from ..bags import JOINT_STATES, PLANT_INPUT, REFERENCE_TOPIC, read_estimates, read_joint_series, read_references
from ..conformance import model as mdl
from ..conformance.estimators import Estimator
from ..errors import ReachsetError
from ..systems.plant import lwa4p_joint_plant
from . import recorded_loop as rl
from .config import SearchSpace, components_from_gains, load_config, u_max_for
from .modes import synthesize
from .problem import problems_from_series
from .reference_error import ReferenceClass, ReferenceMethod


def iterate(record, series, space, *, iterations=2, final_reidentify=True, plant=None, estimator=None,
            horizon=125, u_max=26.0, u_ff=2.0, search=None, seed=0,
            reference_method=ReferenceMethod.REFERENCE_SET, dt=0.004, allow_weak_horizon=False,
            reference_class=None, initial_state_set=True):
    """The paper's iterative procedure (Sec. III-D, Fig. 4).

    ``initial_state_set``: Theorem 1 with the estimator's initial-state set (default, as
    :func:`synthesize_bags`); false: the paper's eq. 13.

    Data without references need ``reference_class`` (:class:`ReferenceClass`, Appendix B).

    ``horizon`` obeys :func:`reachset_ros.conformance.kernels.require_minimum_horizon`.

    1. synthesise (combined) on the initial data ``series``;
    2. ``record(gains)`` with the new gains (``{joint: gains}``) returns new data: a list of bag
       paths, ``{joint: JointSeries}`` or ``({joint: JointSeries}, {joint: [Reference]})`` (e.g.
       :func:`reachset_ros.sim.recordings.recordings_series` of
       :func:`reachset_ros.sim.recordings.simulate_arm_recordings`; the simulator or the node
       suite drives the robot), or ``(series, references, estimates)`` (``estimates``: ``{joint: (stamps, ndarray
       (T, 3))}``, the recorded ``/observer/estimate`` as :func:`reachset_ros.bags.read_estimates`
       gives it);
    3. repeat 1-2 ``iterations`` times in total, each synthesis seeded with the kept gains;
       then, if ``final_reidentify``, record once more and re-identify the sets with the
       controller fixed. When that recording holds estimates (bags with
       ``/observer/estimate`` or the three-tuple) and references, the sets must also hold its
       recorded loop (:func:`reachset_ros.synthesis.recorded_loop.constrain`, as
       ``synthesize --mode reidentify``), and a loop recorded with the kept gains that still
       leaves R*_e is refused (:func:`~reachset_ros.synthesis.recorded_loop.require_inside`,
       issue 34.5).

    No drift to worse gains: per joint the synthesis with the smallest guaranteed ‖R*_e‖ so
    far is *kept* (each ‖R*_e‖ is guaranteed for the data it was synthesised on); the next
    recording, the next synthesis's seed and the re-identification use the kept gains.

    Raises
    ------
    RecordedLoopError
        The re-identification's own recorded loop leaves its R*_e.

    Returns
    -------
    list of dict
        One ``{"step": ..., "results": {joint: JointResult}}`` per synthesis/re-identification;
        the last entry also has ``"kept": {joint: step}``, the synthesis whose gains were kept
        (an entry ``{"step": "kept", ...}`` with the kept results when ``final_reidentify`` is
        false).
    """
    plant = plant or lwa4p_joint_plant(dt=dt)
    estimator = estimator or Estimator.named(defaults.get("synthesis.estimator"), plant)
    cf.require_minimum_horizon(plant, horizon, allow_weak_horizon)
    thm = cf.Theorem1.build(plant, horizon, estimator if initial_state_set else None)
    history = []
    data, refs = _as_series(series, dt)
    prev = None
    best = {}                      # joint -> (guaranteed ||R*_e||, step, JointResult)
    if not isinstance(series, (dict, tuple)) and not data:
        raise ReachsetError("iterate: no data")
    for it in range(int(iterations)):
        probs = problems_from_series(data, plant, estimator, horizon, u_max, u_ff, refs,
                                     reference_method=reference_method, thm=thm, reference_class=reference_class)
        seeds = {n: [r.params] for n, r in prev.items()} if prev else None
        res = synthesize(probs, space, "combined", search, seed, seeds, with_separate=(it == 0))
        step = f"synthesis {it + 1}"
        history.append({"step": step, "results": res})
        for n, r in res.items():
            if n not in best or r.re_norm < best[n][0]:
                best[n] = (float(r.re_norm), step, r)
        prev = {n: b[2] for n, b in best.items()}
        if it + 1 < iterations or final_reidentify:
            raw = record({n: r.gains() for n, r in prev.items()})
            data, refs = _as_series(raw, dt)
    kept = {n: b[1] for n, b in best.items()}
    if final_reidentify and prev:
        probs = problems_from_series(data, plant, estimator, horizon, u_max, u_ff, refs,
                                     reference_method=reference_method, thm=thm, reference_class=reference_class)
        gains = {n: r.gains() for n, r in prev.items()}
        # the sets must also hold the loop recorded with the kept gains (issue 34.5), as in
        # solve(): its rows, then refused if it still leaves R*_e
        loops = _iterate_loops(raw, plant, gains, dt)
        probs = [rl.constrain(pb, gains[pb.name], loops.get(pb.name)) for pb in probs]
        res = synthesize(probs, space, "reidentify", gains=gains)
        rl.require_inside(res)
        history.append({"step": "re-identification", "results": res, "kept": kept})
    elif prev:
        history.append({"step": "kept", "results": prev, "kept": kept})
    return history


def _as_series(data, dt):
    """``(series, references)`` of bag paths, ``{joint: JointSeries}``, ``(series, references)``
    or ``(series, references, estimates)``."""
    if isinstance(data, dict):
        return data, {}
    if isinstance(data, tuple) and len(data) in (2, 3) and isinstance(data[0], dict):
        return data[0], dict(data[1] or {})
    paths = [Path(p) for p in data]
    series, _ = read_joint_series(paths, None, dt)
    return series, read_references(paths, list(series), dt)


def _iterate_loops(data, plant, gains, dt):
    """``{joint: LoopExtremes or None}``: the loop a recording of :func:`iterate`'s ``record``
    holds with ``gains`` (:mod:`~reachset_ros.synthesis.recorded_loop`): bag paths (their
    ``/observer/estimate``, bag by bag as :func:`_recorded_loops`) or ``(series, references,
    estimates)`` with ``estimates`` ``{joint: (stamps, ndarray (T, 3))}``
    (:func:`reachset_ros.bags.read_estimates`); empty for data without estimates."""
    loops = {n: components_from_gains(g, plant.dt) for n, g in gains.items()}
    if isinstance(data, dict):
        return {}
    if isinstance(data, tuple) and isinstance(data[0], dict):
        if len(data) < 3 or not data[2]:
            return {}
        series, refs, est = data[0], dict(data[1] or {}), data[2]
        return {n: rl.series_loop_extremes(plant, *loops[n], series[n], est.get(n), refs.get(n, ()))
                for n in loops if n in series}
    parts = {n: [] for n in loops}
    for bag in (Path(p) for p in data):
        series, _ = read_joint_series([bag], None, dt)
        refs = read_references([bag], list(series), dt)
        est = read_estimates([bag], list(series)) or {}
        for n in parts:
            if n in series:
                parts[n].append(rl.series_loop_extremes(plant, *loops[n], series[n], est.get(n), refs.get(n, ())))
    return {n: rl.merge(v) for n, v in parts.items()}


# ====================================================================== bags in, model out
@dataclass(kw_only=True)
class BagSynthesis:
    """Everything :func:`synthesize_bags` computed (the CLI and the synthesis node use it)."""

    results: dict            # joint -> JointResult
    problems: list           # JointProblem per joint
    report: object           # bags.ReadReport
    plant: object
    plant_spec: dict
    estimator: object
    horizon: int
    space: object            # SearchSpace (None for reidentify)
    mode: str
    seed: int
    reference_method: int
    bags: tuple
    minimum_horizon: int = None         # the plant's minimum k* (kernels.minimum_horizon)
    horizon_below_minimum: bool = False  # k* accepted below it (allow_weak_horizon)
    reference_class: object = None      # ReferenceClass used instead of/over the recorded references
    inflation: object = 0.0             # float or {joint: float}: R*_e, R*_u are for the inflated sets
    initial_state_set: bool = False     # Theorem 1 with the estimator's initial-state set (Theorem1.build)
    sha256: tuple = None                # the bags' hashes when a fleet's workers computed them
    input_source: dict = None           # how the bags' u_p was computed (conformance.model.input_source_of)

    def as_dict(self):
        d = {"mode": self.mode, "joints": {n: r.as_dict() for n, r in self.results.items()},
             "data": self.report.as_dict(), "reference_method": self.reference_method, "seed": self.seed,
             "horizon": self.horizon, "minimum_horizon": self.minimum_horizon,
             "horizon_below_minimum": self.horizon_below_minimum,
             "reference_class": self.reference_class.as_dict() if self.reference_class is not None else None,
             "inflation": max((float(r.inflation) for r in self.results.values()), default=0.0),
             "inflations": {n: float(r.inflation) for n, r in self.results.items()},   # per joint (issue 35.1)
             "initial_state_set": bool(self.initial_state_set)}
        if self.space is not None:
            d.update(observer=self.space.observer, controller=self.space.controller, free=list(self.space.free),
                     search_box={n: list(self.space.bounds[n]) for n in self.space.free})
        return d

    def model(self, command=""):
        """The :class:`reachset_ros.conformance.model.ConformanceModel` of the results (gains per joint)."""
        joints = {}
        for n, r in self.results.items():
            joints[n] = mdl.JointSets(alpha_w=tuple(r.alpha_w.tolist()), alpha_v=tuple(r.alpha_v.tolist()),
                                      c_w=tuple(r.c_w.tolist()), c_v=tuple(r.c_v.tolist()), test_cases=r.test_cases,
                                      horizon=self.horizon, gains=r.gains(),
                                      extra={"reference_error": r.reference, "conformant": r.conformant},
                                      inflation=float(r.inflation))     # the inflation its R*_u is certified for
        return mdl.ConformanceModel(plant=self.plant, plant_spec=self.plant_spec, estimator=self.estimator,
                                    horizon=self.horizon, joints=joints,
                                    inflation=max((j.inflation for j in joints.values()), default=0.0),
                                    provenance=mdl.provenance(self.bags, command, self.sha256),
                                    minimum_horizon=self.minimum_horizon,
                                    horizon_below_minimum=self.horizon_below_minimum,
                                    initial_state_set=bool(self.initial_state_set),
                                    input_source=self.input_source)


@dataclass(frozen=True, kw_only=True)
class SynthesisOptions:
    """What to synthesise from bags and how (``reachset synthesize``'s options, as values).

    Attributes
    ----------
    joints : list of str or None
        None: all joints on both topics (reidentify: the model's joints).
    mode : {"combined", "separate", "reidentify"}
    observer, controller, free, fix, bounds, eso_input
        The search space (:meth:`SearchSpace.from_config`).
    u_max : float, list (one per joint) or dict, optional
        Default: the gains' ``u_max`` (reidentify), else the config's per-joint value.
    u_ff, horizon, estimator, alpha_lower, reference_method, seed, lqg_r
        See the CLI.
    config : path of a synthesis config (default ``config/synthesis.yaml``)
    model : path of a model file (mode reidentify: its gains are kept; its plant, estimator
        and horizon are used unless given)
    allow_weak_horizon : bool
        Accept a horizon below the plant's minimum (recorded in the model); otherwise such a
        horizon is refused (:func:`reachset_ros.conformance.kernels.require_minimum_horizon`,
        the rule ``identify`` applies too).
    reference_class : ReferenceClass or str, optional
        Bound the reference error (Appendix B) over this class instead of the bags'
        ``/reference`` (which must then lie in it). Without it every joint needs recorded
        references (reidentify: or a class recorded in the model); otherwise refused.
    topics : (str, str), optional
        Measurement and plant-input topics (default ``/joint_states``, ``/plant_input``).
    reader : dict, optional
        More :func:`reachset_ros.bags.read_joint_series` options (``effort``, ``joint_names``).
    inflation : float, optional
        The monitor checks the sets scaled by ``1 + inflation``; R*_u inside U_p is enforced
        and R*_e reported for those sets, and the model records it (every joint). Default 0
        (reidentify: each joint's own inflation in the model).
    initial_state_set : bool, optional
        Theorem 1 with the estimator's initial-state set
        (:meth:`reachset_ros.conformance.theorem1.Theorem1.build`); recorded in the model.
        Default true (reidentify: the model's); false: the paper's eq. 13 (docs/synthesis.md,
        "Where the room in ||R*_e|| is").
    """

    joints: list | None = None
    mode: str = "combined"
    observer: str = "hg"
    controller: str | None = None
    free: list | None = None
    fix: dict | None = None
    bounds: dict | None = None
    u_max: object = None
    u_ff: float | None = None
    horizon: int | None = None
    estimator: str | None = None
    alpha_lower: list | None = None
    reference_method: int = ReferenceMethod.REFERENCE_SET
    eso_input: str = "previous"
    seed: int | None = None
    lqg_r: tuple = ()
    config: str | None = None
    model: str | None = None
    dt: float = 0.004
    allow_weak_horizon: bool = False
    reference_class: object = None
    inflation: float | None = None
    topics: tuple | None = None
    reader: dict | None = None
    initial_state_set: bool | None = None


@dataclass(frozen=True, kw_only=True)
class SynthesisPlan:
    """What a synthesis from bags fixes before any bag is read (:func:`plan`).

    ``names``: the joints asked for (None: all); ``gains``, ``model_classes``: reidentify's
    kept gains and recorded reference classes per joint; ``loops``: reidentify's kept loops
    ({name: (observer, controller)}) whose recorded closed loop the sets must also hold
    (:mod:`~reachset_ros.synthesis.recorded_loop`).
    """

    bags: tuple
    options: SynthesisOptions
    cfg: dict
    plant: object
    plant_spec: dict
    estimator: object
    horizon: int
    thm: object
    names: list | None
    gains: dict | None
    model_classes: dict
    space: object
    inflation: object           # float (every joint) or {joint: float} (reidentify: the model's per joint)
    initial_state_set: bool
    minimum_horizon: int
    horizon_below_minimum: bool
    loops: dict | None


@dataclass(frozen=True, kw_only=True)
class BagData:
    """The bags' data a synthesis needs: the series (one process, :func:`read_bags`) or, from
    a fleet's sweep (:mod:`reachset_ros.fleet`, chosen by the workflow), the deviation
    extremes with a ``checker`` that counts a non-conformant xi's violating ticks.

    ``references`` {name: [Reference]}; ``loops`` {name: LoopExtremes or None} (reidentify);
    ``sha256`` the bags' hashes when the fleet's workers computed them.
    """

    names: list
    series: dict | None
    devs: dict | None
    report: object
    references: dict
    loops: dict | None = None
    sha256: tuple | None = None
    checker: object = None


def plan(bags, options: SynthesisOptions):
    """Check ``options`` and fix everything that does not need the bags (:class:`SynthesisPlan`):
    the plant, estimator, horizon and Theorem-1 rows, the search space or (reidentify) the
    kept gains of ``options.model``."""
    o = options
    cfg = load_config(o.config)
    bags = tuple(Path(b) for b in bags)
    if o.mode not in ("combined", "separate", "reidentify"):
        raise ReachsetError(f"unknown mode {o.mode!r} (combined, separate or reidentify)")
    if o.mode == "reidentify":
        if not o.model:
            raise ReachsetError("mode reidentify needs a model file whose gains are kept")
        base = mdl.load(o.model)
        mdl.require_input_source(base, (o.reader or {}).get("effort"), source=o.model)
        plant, plant_spec = base.plant, base.plant_spec
        horizon = base.horizon if o.horizon is None else int(o.horizon)
        est = base.estimator if o.estimator is None else Estimator.named(o.estimator, base.plant)
        gains = {n: j.gains for n, j in base.joints.items()}
        model_classes = {n: (j.extra or {}).get("reference_error", {}).get("reference_class")
                         for n, j in base.joints.items()}
        names = list(base.joints) if not o.joints else list(o.joints)
        for n in names:
            if n not in base.joints:
                raise ReachsetError(f"joint {n} is not in the model {o.model}")
        space = None
        inflation = base.inflations() if o.inflation is None else o.inflation
        initial_state_set = base.initial_state_set if o.initial_state_set is None else o.initial_state_set
    else:
        if o.model:
            raise ReachsetError("a model file is only used with mode reidentify")
        plant, plant_spec = lwa4p_joint_plant(dt=o.dt), {"kind": "lwa4p_joint", "dt": o.dt}
        horizon = 125 if o.horizon is None else int(o.horizon)
        est = Estimator.named(o.estimator or defaults.get("synthesis.estimator"), lwa4p_joint_plant(dt=o.dt))
        gains, names = None, (list(o.joints) if o.joints else None)
        model_classes = {}
        space = SearchSpace.from_config(cfg, observer=o.observer, controller=o.controller, free=o.free, fix=o.fix,
                                        bounds=o.bounds, eso_input=o.eso_input, dt=o.dt)
        inflation, initial_state_set = o.inflation, o.initial_state_set
    if horizon < 0:
        raise ReachsetError("horizon must be >= 0")
    inflation = 0.0 if inflation is None else inflation
    inflation = ({n: float(x) for n, x in inflation.items()} if isinstance(inflation, dict) else float(inflation))
    for x in (inflation.values() if isinstance(inflation, dict) else (inflation,)):
        if not (math.isfinite(x) and x >= 0):
            raise ReachsetError(f"inflation must be finite and >= 0, got {x}")
    k_min, weak = cf.require_minimum_horizon(plant, horizon, o.allow_weak_horizon)
    initial_state_set = True if initial_state_set is None else bool(initial_state_set)
    thm = cf.Theorem1.build(plant, horizon, est if initial_state_set else None)
    # reidentify: the kept gains' loops, to read the bags' recorded closed loop (recorded_loop)
    loops = ({n: components_from_gains(gains[n], plant.dt) for n in names if gains.get(n)}
             if o.mode == "reidentify" else None)
    return SynthesisPlan(bags=bags, options=o, cfg=cfg, plant=plant, plant_spec=plant_spec, estimator=est,
                         horizon=horizon, thm=thm, names=names, gains=gains, model_classes=model_classes, space=space,
                         inflation=inflation, initial_state_set=initial_state_set, minimum_horizon=k_min,
                         horizon_below_minimum=weak, loops=loops)


def read_bags(pl: SynthesisPlan):
    """The bags' series, references and (reidentify) recorded loops, read in this process."""
    o, plant = pl.options, pl.plant
    series, report = read_joint_series(list(pl.bags), pl.names, plant.dt, _topics(o), **(o.reader or {}))
    names = list(series)
    cf.require_horizon(series, pl.estimator.history, pl.horizon, pl.bags)
    _require_gains(pl, names)
    refs = read_references(list(pl.bags), names, plant.dt)
    loop_ext = _recorded_loops(pl, names) if pl.loops else None
    return BagData(names=names, series=series, devs=None, report=report, references=refs, loops=loop_ext)


def _topics(o):
    return tuple(o.topics) if o.topics else (JOINT_STATES, PLANT_INPUT)


def _recorded_loops(pl: SynthesisPlan, names):
    """The recorded loops of the re-identified joints, bag by bag, merged exactly
    (:func:`reachset_ros.synthesis.recorded_loop.merge`): estimates and references are paired
    with the measurements of their own bag, as the fleet's per-bag tasks do
    (:func:`reachset_ros.fleet.tasks.bag_extremes`), so that bags whose stamps overlap give the
    same rows in one process as on a fleet (issue 34.12; before, one process paired each
    measurement with whichever bag's estimate had its stamp)."""
    o, plant = pl.options, pl.plant
    parts = {n: [] for n in names if n in pl.loops}
    for bag in pl.bags:
        series, _ = read_joint_series([bag], pl.names, plant.dt, _topics(o), **(o.reader or {}))
        refs = read_references([bag], list(series), plant.dt)
        est = read_estimates([bag], list(series)) or {}
        for n in parts:
            if n in series:
                parts[n].append(rl.series_loop_extremes(plant, *pl.loops[n], series[n], est.get(n), refs.get(n, ())))
    return {n: rl.merge(v) for n, v in parts.items()}


def _require_gains(pl: SynthesisPlan, names):
    if pl.options.mode == "reidentify":
        missing = [n for n in names if not pl.gains.get(n)]
        if missing:
            raise ReachsetError(f"joint {missing[0]}: the model {pl.options.model} has no gains to keep fixed")


def _u_max(pl: SynthesisPlan, names):
    """U_p per joint: ``options.u_max`` (one value, one per joint or a dict), else the kept
    gains' (reidentify) or the config's."""
    u_max, gains, cfg = pl.options.u_max, pl.gains, pl.cfg
    if u_max is None:
        um = {n: float(gains[n]["u_max"]) if gains and "u_max" in gains.get(n, {}) else u_max_for(cfg, n)
              for n in names}
    elif isinstance(u_max, dict):
        um = {n: float(u_max[n]) if n in u_max else u_max_for(cfg, n) for n in names}
    else:
        vals = list(np.atleast_1d(np.asarray(u_max, float)))
        if len(vals) == 1:
            um = {n: vals[0] for n in names}
        elif len(vals) == len(names):
            um = dict(zip(names, vals))
        else:
            raise ReachsetError(f"u_max: {len(vals)} values for {len(names)} joints ({', '.join(names)})")
    for n, v in um.items():
        if not (math.isfinite(v) and v > 0):
            raise ReachsetError(f"joint {n}: u_max must be positive, got {v}")
    return um


def solve(pl: SynthesisPlan, data: BagData):
    """Build the per-joint problems from ``data`` and run the plan's mode (:class:`BagSynthesis`)."""
    o, names = pl.options, data.names
    _require_gains(pl, names)
    um = _u_max(pl, names)
    uff = float(pl.cfg.get("u_ff", 2.0) if o.u_ff is None else o.u_ff)
    search = dict(pl.cfg.get("search", {}))
    seed = int(search.get("seed", 0) if o.seed is None else o.seed)
    if seed < 0:
        raise ReachsetError(f"seed must be >= 0, got {seed}")
    refs = data.references
    classes = _reference_classes(names, refs, o.reference_class, pl.model_classes, pl.bags)
    problems = problems_from_series(data.series, pl.plant, pl.estimator, pl.horizon, um, uff, refs,
                                    reference_method=o.reference_method, alpha_lower=o.alpha_lower, thm=pl.thm,
                                    reference_class=classes, inflation=pl.inflation, devs=data.devs,
                                    checker=data.checker)
    if pl.loops:      # the sets must also hold the closed loop the bags recorded with the kept gains
        loop_ext = data.loops or {}
        problems = [rl.constrain(pb, pl.gains[pb.name], loop_ext.get(pb.name)) for pb in problems]
    results = synthesize(problems, pl.space, o.mode, search, seed, gains=pl.gains, lqg_r=tuple(o.lqg_r or ()))
    if pl.loops:      # the CLI, the synthesis node's worker: nothing applies a loop R*_e leaves (issue 34.5)
        rl.require_inside(results)
    return BagSynthesis(results=results, problems=problems, report=data.report, plant=pl.plant,
                        plant_spec=pl.plant_spec, estimator=pl.estimator, horizon=pl.horizon, space=pl.space,
                        mode=o.mode, seed=seed, reference_method=int(o.reference_method), bags=pl.bags,
                        minimum_horizon=pl.minimum_horizon, horizon_below_minimum=pl.horizon_below_minimum,
                        reference_class=o.reference_class, inflation=pl.inflation,
                        initial_state_set=pl.initial_state_set, sha256=data.sha256,
                        input_source=mdl.input_source_of((o.reader or {}).get("effort")))


def synthesize_bags(bags, options: SynthesisOptions = None, **kw):
    """Read bags, build the per-joint problems and run the mode (what ``reachset synthesize``
    does, in one process; :func:`reachset_ros.workflows.synthesize.synthesize` also sweeps on a
    fleet).

    Parameters
    ----------
    bags : sequence of path
    options : SynthesisOptions, optional
    **kw
        Instead of (or over) ``options``: its fields by name.

    Returns
    -------
    BagSynthesis
    """
    options = replace(options, **kw) if options is not None else SynthesisOptions(**kw)
    pl = plan(bags, options)
    return solve(pl, read_bags(pl))


def _reference_classes(names, refs, reference_class, model_classes, bags):
    """``{joint: ReferenceClass or None}``; refuses a joint with neither references nor a class.

    Appendix B: the reference error of this plant is not zero, so it is bounded over the
    recorded references or over an explicit class (given, or recorded in the model that
    ``reidentify`` starts from).
    """
    if reference_class is not None and not isinstance(reference_class, ReferenceClass):
        reference_class = ReferenceClass.parse(reference_class)
    out = {}
    for n in names:
        rc = reference_class
        if rc is None and not any(len(r) for r in refs.get(n, ())) and model_classes.get(n):
            rc = ReferenceClass.from_dict(model_classes[n])
        if rc is None and not any(len(r) for r in refs.get(n, ())):
            where = ", ".join(str(b) for b in bags)
            what = (f"no {REFERENCE_TOPIC} topic" if not refs else f"no {REFERENCE_TOPIC} samples of joint {n}")
            raise guarantees.refused("G11", f"{where}: {what}; record the references or give --reference-class "
                                            "qdd_max=F[,step_max=F] (the reference error is not zero on this plant, "
                                            "Appendix B)")
        out[n] = rc
    return out
