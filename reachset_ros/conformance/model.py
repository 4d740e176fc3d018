"""The conformance model file (YAML): an identified, immutable value.

Holds everything needed to reproduce a verdict: the plant (the paper's per-joint
LWA-4P model or explicit matrices), per joint the identified sets W = (c_W, G'_W diag
alpha_W) and V = (c_V, G'_V diag alpha_V), the horizon k*, the initial-state estimator,
an inflation per joint (optionally calibrated), optional gains, provenance (input bags and their
SHA-256), and the horizon rule's outcome (``minimum_horizon`` of the plant, and
``horizon_below_minimum: true`` when k* was accepted below it with ``--allow-weak-horizon``;
see :func:`~reachset_ros.conformance.kernels.require_minimum_horizon`; a reader refuses a
model below the minimum that does not record the flag, :func:`require_model_horizon`). ``reachset identify`` and ``reachset synthesize`` write it; ``check``,
``replay`` and the monitor node read it.

Two bindings (issue 34.10/11), checked by the readers:

* ``input_source``: how u_p was computed for the data the sets were identified from
  (``{kind: topic}``: the plant-input topic; ``{kind: effort, urdf_sha256,
  params_sha256, locked_joints, joints, torque_scale}``: from the measured effort with a URDF,
  :meth:`reachset_ros.robot.effort.EffortInput.binding`). ``check``, ``replay`` and the
  monitor refuse data whose u_p comes from another source (:func:`require_input_source`), and
  a model that records none (written before the binding existed): re-identify it, or, when its
  data's u_p came from the plant-input topic, add ``input_source: {kind: topic}``.
* ``calibration``: when the inflation was calibrated (``identify --calibrate``/``--validate``,
  :func:`reachset_ros.workflows.calibrate.calibrate_model`), the digest of the sets it was
  calibrated on (:func:`sets_digest`) and every joint's inflation (``inflations``); every
  reader refuses a model whose sets or inflations are not the record's
  (:func:`require_calibrated_sets`). No record: the inflation was given (``--inflation``), not
  calibrated.

Inflation per joint (issue 35.1): each joint's block carries its ``inflation``; the monitor
checks that joint's sets scaled by ``1 + inflation`` (:meth:`ConformanceModel.checked_xi`). The
model-level ``inflation`` is written as the largest joint value, so a reader that applies one
value to every joint checks sets that only grow; a file whose joints carry none (written before
per-joint inflation) applies its model-level value to every joint.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from .. import guarantees
from ..atomic import write_yaml
from ..errors import ReachsetError, first_line
from . import envelope as _envelope
from .estimators import Estimator
from .kernels import minimum_horizon
from ..systems.plant import LinearPlant, lwa4p_joint_plant

FORMAT = "reachset_ros/model/1"


# Largest horizon k* a model file may ask for: the monitor keeps k*+1 test cases per joint and
# the Theorem-1 normals/offsets per k (the paper uses 125; 100,000 ticks = 400 s at 250 Hz).
MAX_HORIZON = 100_000

@dataclass(frozen=True)
class JointSets:
    """Identified sets and bookkeeping of one joint."""

    alpha_w: tuple
    alpha_v: tuple
    c_w: tuple
    c_v: tuple
    test_cases: int = 0
    horizon: int = 125
    gains: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    inflation: float = None     # this joint's inflation; None: the model's (ConformanceModel.joint_inflation)

    def xi(self, inflation=0.0):
        """Theorem-1 parameter vector [c_W, c_V, (1+inflation) alpha_W, (1+inflation) alpha_V]."""
        s = 1.0 + float(inflation)
        return np.concatenate([np.array(self.c_w, float), np.array(self.c_v, float),
                               s * np.array(self.alpha_w, float), s * np.array(self.alpha_v, float)])


@dataclass(frozen=True)
class ConformanceModel:
    """A reachset-conformant model of a robot's joints (immutable)."""

    plant: LinearPlant
    plant_spec: dict
    estimator: Estimator
    horizon: int
    joints: dict
    inflation: float = 0.0
    provenance: dict = field(default_factory=dict)
    minimum_horizon: int = None          # the plant's minimum k* (None: not recorded, older file)
    horizon_below_minimum: bool = False  # k* accepted below the minimum (a weaker guarantee)
    initial_state_set: bool = False      # Theorem 1 with the estimator's error set (theorem1.Theorem1.build)
    input_source: dict = None            # how u_p was computed (input_source_of); None: not recorded (older file)
    calibration: dict = None             # the inflation's calibration record (calibration_record); None: given
    envelope: object = None              # where the data were (envelope.Envelope, issue 37); None: not recorded

    def theorem1(self):
        """The Theorem-1 rows this model's sets were identified for and are checked with
        (:meth:`reachset_ros.conformance.theorem1.Theorem1.build`; with the estimator's
        initial-state set if ``initial_state_set``): one place for identify, check, replay and
        the monitor."""
        from .theorem1 import Theorem1
        return Theorem1.build(self.plant, self.horizon, self.estimator if self.initial_state_set else None)

    def with_joints(self, joints):
        return replace(self, joints=dict(joints))

    def unvalidated(self, bounds):
        """The parts of a reference class this model was never validated on
        (:func:`reachset_ros.conformance.envelope.unvalidated` of :attr:`envelope`; ``bounds``
        ``{joint: ClassBounds}`` or ``{joint: mapping of its fields}``), or None when the model
        records no envelope (nothing guessed)."""
        if self.envelope is None:
            return None
        return _envelope.unvalidated(self.envelope, {n: b if isinstance(b, _envelope.ClassBounds)
                                                     else _envelope.ClassBounds(**b) for n, b in bounds.items()})

    def joint_inflation(self, joint):
        """The inflation of ``joint``'s sets: its own (``joints.<name>.inflation`` in the file),
        else the model's ``inflation`` (files written before per-joint inflation: one value for
        every joint)."""
        own = self.joints[joint].inflation
        return float(self.inflation if own is None else own)

    def inflations(self):
        """``{joint: inflation}`` of every joint (:meth:`joint_inflation`)."""
        return {n: self.joint_inflation(n) for n in self.joints}

    def largest_inflation(self):
        """The largest joint inflation: the model-level ``inflation`` the file records for
        readers that apply one value to every joint (their sets only grow)."""
        return max(self.inflations().values(), default=float(self.inflation))

    def checked_xi(self, joint):
        """The sets the monitor checks for ``joint``: the Theorem-1 parameter vector of its
        identified W, V scaled by ``1 +`` its own inflation (:meth:`JointSets.xi`,
        :meth:`joint_inflation`). The one place ``check``, ``replay``, the monitor and the
        plots take a joint's checked sets from."""
        return self.joints[joint].xi(self.joint_inflation(joint))

    def with_inflation(self, inflation):
        """This model with ``inflation`` applied: a number for every joint, or ``{joint:
        number}`` for some (the others keep theirs). Each joint carries its value; the
        model-level ``inflation`` becomes the largest (:meth:`largest_inflation`). The
        calibration record is kept: a reader refuses it unless it is these values'
        (:func:`require_calibrated_sets`)."""
        per = dict(inflation) if isinstance(inflation, dict) else {n: inflation for n in self.joints}
        unknown = sorted(set(per) - set(self.joints))
        if unknown:
            raise ReachsetError(f"inflation for joint {unknown[0]}, which is not in the model")
        joints = {n: replace(j, inflation=_inflation(per.get(n, self.joint_inflation(n)), f"joint {n} inflation"))
                  for n, j in self.joints.items()}
        return replace(self, joints=joints, inflation=max(j.inflation for j in joints.values()))


def plant_from_spec(spec):
    """``{"kind": "lwa4p_joint", "dt": 0.004}`` or ``{"kind": "matrices", "A": ..., ...}``."""
    if not isinstance(spec, dict):
        raise ReachsetError("model: 'plant' must be a mapping")
    kind = spec.get("kind")
    try:
        if kind == "lwa4p_joint":
            return lwa4p_joint_plant(dt=float(spec.get("dt", 0.004)))
        if kind == "matrices":
            return LinearPlant(A=spec["A"], B=spec["B"], C=spec["C"], D=spec.get("D"),
                               Gw=spec["Gw"], Gv=spec["Gv"], dt=float(spec.get("dt", 0.004)))
    except KeyError as e:
        raise ReachsetError(f"model: bad plant: no {e.args[0]} given") from None
    except (ValueError, TypeError) as e:
        raise ReachsetError(f"model: bad plant: {first_line(e)}") from e
    raise ReachsetError(f"model: unknown plant kind {kind!r} (lwa4p_joint or matrices)")


def file_sha256(path):
    """SHA-256 of a file, or of a bag directory's files in name order."""
    h = hashlib.sha256()
    p = Path(path)
    files = sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p]
    for q in files:
        h.update(q.name.encode())
        with open(q, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def _floats(v, name, n=None):
    try:
        a = [float(x) for x in (v if isinstance(v, (list, tuple)) else [v])]
    except (TypeError, ValueError):
        raise ReachsetError(f"model: {name} must be numbers, got {v!r}") from None
    if n is not None and len(a) != n:
        raise ReachsetError(f"model: {name} needs {n} values, got {len(a)}")
    if not all(math.isfinite(x) for x in a):
        raise ReachsetError(f"model: {name} must be finite, got {a}")
    return tuple(a)


def _int(v, name):
    if isinstance(v, int) and not isinstance(v, bool):
        return v
    if isinstance(v, bool) or not isinstance(v, (float, str)):
        raise ReachsetError(f"model: {name} must be an integer, got {v!r}")
    try:
        f = float(v)
    except ValueError:
        raise ReachsetError(f"model: {name} must be an integer, got {v!r}") from None
    if not (math.isfinite(f) and f == int(f)):
        raise ReachsetError(f"model: {name} must be an integer, got {v!r}")
    return int(f)


def _fl(v):
    return [float(x) for x in v]


def _inflation(v, name, source="model"):
    x = _floats(v, name, 1)[0]
    if x < 0:
        raise ReachsetError(f"{source}: {name} must be >= 0, got {x:g}")
    return x


def to_dict(model: ConformanceModel) -> dict:
    return {
        "format": FORMAT,
        "plant": model.plant_spec,
        "estimator": model.estimator.as_dict(),
        "horizon": int(model.horizon),
        "inflation": model.largest_inflation(),     # for readers of one inflation: the largest (docs/theory.md)
        "joints": {name: {"alpha_w": _fl(j.alpha_w), "alpha_v": _fl(j.alpha_v),
                          "c_w": _fl(j.c_w), "c_v": _fl(j.c_v),
                          **({"inflation": float(j.inflation)} if j.inflation is not None else {}),
                          "test_cases": int(j.test_cases), "horizon": int(j.horizon),
                          **({"gains": j.gains} if j.gains else {}),
                          **({"extra": j.extra} if j.extra else {})}
                   for name, j in model.joints.items()},
        "provenance": model.provenance,
        **({"minimum_horizon": int(model.minimum_horizon)} if model.minimum_horizon is not None else {}),
        **({"horizon_below_minimum": True} if model.horizon_below_minimum else {}),
        **({"initial_state_set": True} if model.initial_state_set else {}),
        **({"input_source": dict(model.input_source)} if model.input_source is not None else {}),
        **({"calibration": dict(model.calibration)} if model.calibration is not None else {}),
        **({"envelope": _envelope.to_dict(model.envelope)} if model.envelope is not None else {}),
    }


def from_dict(d, source="model") -> ConformanceModel:
    """Validate and build a model; every problem is one :class:`ReachsetError` line."""
    if not isinstance(d, dict):
        raise ReachsetError(f"{source}: not a model file (expected a YAML mapping)")
    if d.get("format") != FORMAT:
        raise ReachsetError(f"{source}: unknown format {d.get('format')!r}, expected {FORMAT}")
    plant = plant_from_spec(d.get("plant"))
    est = Estimator.from_dict(d.get("estimator", {"name": "fd"}))
    try:
        est.validate(plant)
    except ReachsetError as e:
        raise ReachsetError(f"{source}: {e}") from None
    horizon = _int(d.get("horizon", 125), "horizon")
    if not 0 <= horizon <= MAX_HORIZON:
        raise ReachsetError(f"{source}: horizon must be in [0, {MAX_HORIZON}], got {horizon}")
    inflation = _inflation(d.get("inflation", 0.0), "inflation", source)
    joints_in = d.get("joints")
    if not isinstance(joints_in, dict) or not joints_in:
        raise ReachsetError(f"{source}: no joints")
    n, ny = plant.A.shape[0], plant.C.shape[0]
    pw, pv = plant.Gw.shape[1], plant.Gv.shape[1]
    joints = {}
    for name, j in joints_in.items():
        if not isinstance(j, dict):
            raise ReachsetError(f"{source}: joint {name}: expected a mapping")
        aw = _floats(j.get("alpha_w"), f"joint {name} alpha_w", pw)
        av = _floats(j.get("alpha_v"), f"joint {name} alpha_v", pv)
        if min(aw + av) < 0:
            raise ReachsetError(f"{source}: joint {name}: negative scaling factor alpha")
        cw = _floats(j.get("c_w", [0.0] * n), f"joint {name} c_w", n)
        cv = _floats(j.get("c_v", [0.0] * ny), f"joint {name} c_v", ny)
        gains = j.get("gains", {}) or {}
        if not isinstance(gains, dict):
            raise ReachsetError(f"{source}: joint {name}: gains must be a mapping")
        joints[str(name)] = JointSets(aw, av, cw, cv, _int(j.get("test_cases", 0), f"joint {name} test_cases"),
                                      _int(j.get("horizon", horizon), f"joint {name} horizon"), gains,
                                      j.get("extra", {}) or {},
                                      # its own inflation; a file without one (older): the model's (None)
                                      inflation=None if j.get("inflation") is None else
                                      _inflation(j["inflation"], f"joint {name} inflation", source))
    below = d.get("horizon_below_minimum", False)
    if not isinstance(below, bool):
        raise ReachsetError(f"{source}: horizon_below_minimum must be true or false, got {below!r}")
    require_model_horizon(plant, horizon, joints, recorded=d.get("minimum_horizon"), below=below, source=source)
    k_min = d.get("minimum_horizon")
    k_min = None if k_min is None else _int(k_min, "minimum_horizon")
    iss = d.get("initial_state_set", False)
    if not isinstance(iss, bool):
        raise ReachsetError(f"{source}: initial_state_set must be true or false, got {iss!r}")
    if iss:
        try:
            from .theorem1 import initial_error_maps
            initial_error_maps(plant, est)
        except ReachsetError as e:
            raise ReachsetError(f"{source}: {e}") from None
    m = ConformanceModel(plant=plant, plant_spec=dict(d["plant"]), estimator=est, horizon=horizon, joints=joints,
                         inflation=inflation, provenance=d.get("provenance", {}) or {}, minimum_horizon=k_min,
                         horizon_below_minimum=below, initial_state_set=iss,
                         input_source=_input_source(d.get("input_source"), source),
                         calibration=_calibration(d.get("calibration"), source),
                         envelope=None if d.get("envelope") is None else _envelope.from_dict(d["envelope"], source))
    if m.envelope is not None and m.envelope.dt != plant.dt:
        raise ReachsetError(f"{source}: envelope dt {m.envelope.dt:g} is not the plant's {plant.dt:g}")
    require_calibrated_sets(m, source=source)
    if inflation != m.largest_inflation():
        raise ReachsetError(f"{source}: inflation {inflation:g} is not the largest of its joints' own inflations "
                            f"({m.largest_inflation():g}): each joint's inflation is the one checked; the model-level "
                            "value is their largest, for readers of one inflation")
    return m


def require_model_horizon(plant, horizon, joints, *, recorded, below, source):
    """The horizon rule at every reader of a model (``check``, ``replay``, the monitor).

    Theorem 1 (paper eq. 13) constrains every scaling factor alpha only from the plant's
    minimum horizon on (:func:`~reachset_ros.conformance.kernels.minimum_horizon`): below it
    alpha_W is unconstrained by the data and left at zero, so a check at that horizon calls
    almost anything conformant. A model whose k* (or a joint's) is below the minimum is
    refused unless it records ``horizon_below_minimum: true`` (identified with
    ``--allow-weak-horizon``: a weaker guarantee accepted on purpose, which the reader then
    honours); a recorded ``minimum_horizon`` that is not the plant's is refused too.

    Returns
    -------
    int
        The plant's minimum horizon.

    Raises
    ------
    ReachsetError
        Naming the horizon, the minimum and the way to accept a weaker guarantee.
    """
    k_min = minimum_horizon(plant)
    if recorded is not None and _int(recorded, "minimum_horizon") != k_min:
        raise guarantees.refused("G1", f"{source}: minimum_horizon {recorded} is not the plant's minimum horizon "
                                       f"{k_min}")
    shortest = min([horizon] + [j.horizon for j in joints.values()])
    if shortest < k_min and not below:
        raise guarantees.refused("G1", f"{source}: horizon {shortest} is below the plant's minimum horizon {k_min} "
                                       "(Theorem 1 then leaves alpha_W unconstrained); identify with --horizon "
                                       f"{k_min} or more (a model identified with --allow-weak-horizon records "
                                       "horizon_below_minimum: true)")
    return k_min


# ------------------------------------------------------------------ how u_p was computed (34.10)
#: ``input_source`` of data whose u_p is the plant-input topic (``--input topic``, the default)
PLANT_INPUT = {"kind": "topic"}
_EFFORT_KEYS = ("urdf_sha256", "params_sha256", "locked_joints", "joints", "torque_scale")


def input_source_of(effort=None):
    """The ``input_source`` block of data read with ``effort`` (an
    :class:`~reachset_ros.robot.effort.EffortInput` for ``--input effort`` / the monitor's
    ``input_source: effort``; None: the plant-input topic)."""
    return dict(PLANT_INPUT) if effort is None else effort.binding()


def _input_source(v, source):
    if v is None:
        return None
    if not isinstance(v, dict) or v.get("kind") not in ("topic", "effort"):
        raise ReachsetError(f"{source}: input_source must be a mapping with kind topic or effort, got {v!r}")
    if v["kind"] == "effort":
        missing = [k for k in _EFFORT_KEYS if k not in v]
        if missing:
            raise ReachsetError(f"{source}: input_source of kind effort has no {missing[0]}")
    return dict(v)


def _describe_source(b):
    if b["kind"] == "topic":
        return "the plant-input topic"
    params = "no parameter document" if b.get("params_sha256") is None else f"parameters {b['params_sha256'][:12]}"
    return f"effort with URDF {b['urdf_sha256'][:12]}, {params}"


def require_input_source(model: ConformanceModel, effort=None, *, source):
    """Refuse to check data whose u_p is not computed the way the model's data's was (issue 34.10).

    The sets W, V bound the model error of the plant input u_p as it was computed when they
    were identified (paper eq. 6 inverted with the nominal M, psi when it comes from the
    effort): u_p computed another way (the topic instead of the effort, another URDF, other
    identified parameters, other locked joints or torque scale) is another signal, and a
    verdict on it says nothing about the model. ``check``, ``replay`` and the monitor call this
    with the source they read u_p from (``effort``: :class:`~reachset_ros.robot.effort.EffortInput`
    or None for the plant-input topic).

    A model that records no ``input_source`` (written before the binding existed) is refused
    too: which source it was identified from is unknown (module docstring: how to bind it).

    Raises
    ------
    ReachsetError
        One line naming the model, both sources and the first field that differs.
    """
    have = input_source_of(effort)
    rec = model.input_source
    if rec is None:
        raise guarantees.refused("G17", f"{source}: the model records no input_source (how u_p was computed when it was "
                            f"identified; written before issue 34.10): re-identify it, or, if its data's u_p came "
                            f"from the plant-input topic, add the line 'input_source: {{kind: topic}}'")
    if rec["kind"] != have["kind"]:
        raise guarantees.refused("G17", f"{source}: the model was identified with u_p from {_describe_source(rec)}, but this u_p "
                            f"comes from {_describe_source(have)} (--input / the monitor's input_source)")
    for k in _EFFORT_KEYS if rec["kind"] == "effort" else ():
        a, b = rec.get(k), have.get(k)
        if k == "locked_joints":
            a, b = sorted(a or ()), sorted(b or ())
        if k == "torque_scale":
            a, b = [float(x) for x in a], [float(x) for x in b]
        if a != b:
            raise guarantees.refused("G17", f"{source}: the model's u_p was computed from effort with {k} {a}, this u_p with "
                                f"{b} (--robot, --nominal, --lock-joints / the monitor's robot_* parameters)")
    return rec


# ------------------------------------------------------------------ the sets the inflation was calibrated on (34.11)
def sets_digest(model: ConformanceModel):
    """SHA-256 of what the monitor checks besides the inflation: the plant, the estimator, the
    horizon, the Theorem-1 variant and every joint's sets (c_W, c_V, alpha_W, alpha_V, k*).
    Floats enter as their shortest round-trip text, so the digest survives the YAML file."""
    canon = {"plant": model.plant_spec, "estimator": model.estimator.as_dict(), "horizon": int(model.horizon),
             "initial_state_set": bool(model.initial_state_set),
             "joints": {n: [_fl(j.alpha_w), _fl(j.alpha_v), _fl(j.c_w), _fl(j.c_v), int(j.horizon)]
                        for n, j in sorted(model.joints.items())}}
    text = json.dumps(canon, sort_keys=True, default=lambda x: x.tolist() if hasattr(x, "tolist") else repr(x))
    return hashlib.sha256(text.encode()).hexdigest()


def calibration_record(model: ConformanceModel, *, method, **details):
    """The model's ``calibration`` block: ``method`` (``cross_validation`` or
    ``held_out_bags``), the inflation applied to each joint (``inflations``; ``inflation``: the
    largest, as records before per-joint inflation had it) and the digest of the sets it was
    calibrated for (:func:`sets_digest` of ``model``, which must already hold its final sets
    and inflations), and ``details`` (folds, grid, per joint values before any margin
    ``per_joint``, the rule that made the fold sets)."""
    return {"method": str(method), "inflation": model.largest_inflation(), "inflations": model.inflations(),
            "sets_sha256": sets_digest(model), **details}


def with_calibration(model: ConformanceModel, *, method, **details):
    """``model`` with its :func:`calibration_record`."""
    return replace(model, calibration=calibration_record(model, method=method, **details))


def _calibration(v, source):
    if v is None:
        return None
    if not isinstance(v, dict) or not isinstance(v.get("sets_sha256"), str) or "inflation" not in v:
        raise ReachsetError(f"{source}: calibration must be a mapping with sets_sha256 and inflation")
    _floats(v["inflation"], "calibration inflation", 1)
    per = v.get("inflations")
    if per is not None:
        if not isinstance(per, dict):
            raise ReachsetError(f"{source}: calibration inflations must be a mapping joint -> inflation")
        for n, x in per.items():
            _floats(x, f"calibration inflation of joint {n}", 1)
    return dict(v)


def require_calibrated_sets(model: ConformanceModel, *, source):
    """Refuse a model whose calibration record is not for its own sets and inflation (34.11).

    The inflation is an empirical calibration of *these* sets' held-out violations
    (:mod:`reachset_ros.conformance.calibration`): the same number on other sets (the
    synthesis optimum instead of identify's min ||W||+||V|| sets, another horizon or
    estimator) or another number on these sets was never checked. Every reader of a model
    runs this (:func:`from_dict`). A model without a record has a given, uncalibrated inflation.
    """
    rec = model.calibration
    if rec is None:
        return
    if rec["sets_sha256"] != sets_digest(model):
        raise guarantees.refused("G18", f"{source}: its inflation was calibrated on other sets than the ones it holds "
                            f"(calibration sets_sha256 {rec['sets_sha256'][:12]}, the model's sets "
                            f"{sets_digest(model)[:12]}); calibrate these sets (identify --calibrate, or "
                            "workflows.calibrate.calibrate_model for a synthesis) or drop the calibration record")
    # per joint (a record written before per-joint inflation: its one inflation for every joint)
    want = rec.get("inflations") or {n: rec["inflation"] for n in model.joints}
    for n in model.joints:
        have = model.joint_inflation(n)
        if n not in want or float(want[n]) != have:
            cal = "none" if n not in want else f"{float(want[n]):g}"
            raise guarantees.refused("G18", f"{source}: joint {n}: inflation {have:g} is not the calibrated {cal} of its "
                                            "calibration record")
    if float(rec["inflation"]) != float(model.inflation):
        raise guarantees.refused("G18", f"{source}: inflation {model.inflation:g} is not the calibrated "
                                        f"{float(rec['inflation']):g} of its calibration record")


def load(path) -> ConformanceModel:
    p = Path(path)
    if p.is_dir():
        raise ReachsetError(f"{p}: is a directory, not a model file")
    if not p.is_file():
        raise ReachsetError(f"{p}: model file not found")
    try:
        d = yaml.safe_load(p.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise ReachsetError(f"{p}: model file does not parse ({type(e).__name__})") from None
    except OSError as e:
        raise ReachsetError(f"{p}: model file not readable ({e.strerror or type(e).__name__})") from None
    try:
        return from_dict(d, str(p))
    except ReachsetError as e:           # every message names the file
        msg = str(e)
        raise ReachsetError(msg if msg.startswith(str(p)) else f"{p}: {msg.removeprefix('model: ')}") from None


def save(model: ConformanceModel, path):
    """Write atomically (temporary file in the same directory, then rename)."""
    p = Path(path)
    d = to_dict(model)
    p.parent.mkdir(parents=True, exist_ok=True)
    write_yaml(p, d)


def provenance(bags, command, sha256=None):
    """The model file's provenance: when, by which command, from which bags (path and
    :func:`file_sha256`; ``sha256``: the hashes when already computed, e.g. by a fleet's
    workers, in bag order)."""
    hashes = [file_sha256(b) for b in bags] if sha256 is None else list(sha256)
    return {"created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "command": command,
            "bags": [{"path": str(b), "sha256": h} for b, h in zip(bags, hashes)]}
