"""The real Schunk LWA-4P recordings: reading, nominal-model identification, bag import.

Pure core (no ROS). Data layout (data/lwa4p_iros2018/README.md): ``DIR/measurement_i/``
with ``trajectory.csv`` (N x 12: q1..q6 [rad], qd1..qd6 [rad/s]), ``input.csv`` (N-1 x 6:
logged motor torque command, units unknown) and ``time.csv`` (N, seconds, 4 ms steps).

Identification (:func:`fit_nominal`): the nominal model M_hat, psi_hat used by the
controller's feedback linearization (paper eq. 6) and by :func:`import_runs` for
``u_p = M_hat(q)^-1 (s * tau_logged - psi_hat(q, qd))`` is fitted on the 75 training runs
only (``--runs train``: run numbers not divisible by 4, :func:`is_held_out`), with
:func:`reachset_ros.robot.inertial_id.identify_inertial`; the other 25 are held out. Preprocessing
(:class:`Preprocessing`): zero-phase 4th-order Butterworth low-pass (``cutoff_hz``) on the
velocities and on the logged torques of each run, accelerations by central differences of
the filtered velocities, the torque of row k paired with the motion sample ``k + lag``
(the paper's plant has one sample of input and one of output delay, Appendix A), the
first and last ``trim`` samples of each run dropped.
"""
from __future__ import annotations

import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np


from ..atomic import write_yaml
from ..bags import JOINT_STATES, PLANT_INPUT, BagWriter, joint_state, plant_input
from ..errors import ReachsetError
from .dynamics import (RobotModel, create_data, load_model,
                       min_mass_eigenvalue, model_params_dict)
from .effort import plant_inputs as effort_plant_inputs
from .inertial_id import BaseParameters, Identification, identify_inertial, predict_logged, torque_gram

DT = 0.004
#: Stamp of the first sample of the first imported run: 2018-10-01T00:00:00Z (IROS 2018).
DEFAULT_START_NS = 1_538_352_000 * 1_000_000_000
#: Pause inserted between consecutive runs in an imported bag.
DEFAULT_GAP_NS = 1_000_000_000
NOMINAL_FILE = "lwa4p_nominal.yaml"


# --------------------------------------------------------------------------- reading

#: Number of recordings in data/lwa4p_iros2018.
N_RUNS = 100
#: The trajectory families of the recordings (runs 1-20, 21-40, 41-60, 61-80 near one pose
#: each; 81-100 sweeping the workspace), for the leave-one-family-out extrapolation figure.
FAMILIES = ((1, 20), (21, 40), (41, 60), (61, 80), (81, 100))


def is_held_out(run: int) -> bool:
    """The real-data protocol (docs/real-data.md): runs whose number is divisible by 4 are
    held out, never used to fit the nominal model, the sets or an inflation."""
    return int(run) % 4 == 0


def parse_runs(spec: str) -> list:
    """Run numbers of a spec: ranges ``"1-70"``, ``"1,3,5-9"`` (1-based), or the protocol's
    names ``"train"`` (the 75 runs not divisible by 4) and ``"heldout"`` (the 25 that are);
    ``"A-B:train"`` / ``"A-B:heldout"`` keep those of a range."""
    spec = str(spec).strip()
    keep = None
    if ":" in spec:
        spec, keep = (x.strip() for x in spec.rsplit(":", 1))
        if keep not in ("train", "heldout"):
            raise ReachsetError(f"bad run range {spec}:{keep!r} (after ':' expected train or heldout)")
    if spec in ("train", "heldout"):
        spec, keep = f"1-{N_RUNS}", spec
    runs = []
    for part in spec.split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)(?:\s*-\s*(\d+))?", part)
        if not m:
            raise ReachsetError(f"bad run range {spec!r} (expected e.g. 1-70 or 1,3,5-9)")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) else a
        if a < 1 or b < a:
            raise ReachsetError(f"bad run range {spec!r}: {part} is empty or starts below 1")
        runs.extend(range(a, b + 1))
    if len(set(runs)) != len(runs):
        raise ReachsetError(f"bad run range {spec!r}: runs repeat")
    if keep is not None:
        runs = [r for r in runs if is_held_out(r) == (keep == "heldout")]
        if not runs:
            raise ReachsetError(f"bad run range {spec}:{keep}: no {keep} run in it")
    return runs


@dataclass(frozen=True)
class Run:
    """One recording: ``t`` (N,), ``q``, ``qd`` (N, 6) and logged torques ``tau`` (N-1, 6)."""

    index: int
    path: Path
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray

    @property
    def n_samples(self) -> int:
        return len(self.t)


def _load_csv(path: Path, cols: int) -> np.ndarray:
    if not path.is_file():
        raise ReachsetError(f"{path}: file not found")
    try:
        a = np.loadtxt(path, delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError as e:
        raise ReachsetError(f"{path}: malformed CSV ({str(e).splitlines()[0]})") from e
    if a.shape[1] != cols:
        raise ReachsetError(f"{path}: expected {cols} columns, found {a.shape[1]}")
    if not np.all(np.isfinite(a)):
        r = int(np.argwhere(~np.isfinite(a))[0, 0]) + 1
        raise ReachsetError(f"{path}: non-finite value in row {r}")
    return a


#: The real recordings shipped with the package (CC0; source and licence in its README.md and
#: LICENSE): 100 runs of the paper's Schunk LWA-4P (Liu and Althoff, IROS 2018).
RECORDINGS_DIR = Path(__file__).resolve().parents[1] / "data" / "lwa4p_iros2018"


def recordings_dir(root=None) -> Path:
    """The directory of the LWA-4P recordings: ``root``, or the shipped :data:`RECORDINGS_DIR`.

    Parameters
    ----------
    root : path-like, optional
        A directory with ``measurement_<i>/`` folders; ``None`` for the recordings shipped
        in ``reachset_ros/data/lwa4p_iros2018``.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ReachsetError
        The directory does not exist (naming the place it was expected).
    """
    d = RECORDINGS_DIR if root is None else Path(root)
    if not d.is_dir():
        what = "the shipped LWA-4P recordings" if root is None else "data directory"
        raise ReachsetError(f"{d}: {what} not found")
    return d


def read_run(root, index: int) -> Run:
    """Read and validate ``root/measurement_<index>`` (``root=None``: :data:`RECORDINGS_DIR`)."""
    d = recordings_dir(root) / f"measurement_{index}"
    if not d.is_dir():
        raise ReachsetError(f"{d}: run directory not found")
    x = _load_csv(d / "trajectory.csv", 12)
    u = _load_csv(d / "input.csv", 6)
    t = _load_csv(d / "time.csv", 1)[:, 0]
    N = len(x)
    if N < 2:
        raise ReachsetError(f"{d / 'trajectory.csv'}: fewer than 2 samples")
    if len(t) != N:
        raise ReachsetError(f"{d / 'time.csv'}: {len(t)} rows, trajectory.csv has {N}")
    if len(u) != N - 1:
        raise ReachsetError(f"{d / 'input.csv'}: {len(u)} rows, expected {N - 1} "
                            f"(one fewer than trajectory.csv)")
    steps = np.diff(t)
    if np.any(np.abs(steps - DT) > 1e-6):
        k = int(np.argmax(np.abs(steps - DT))) + 2
        raise ReachsetError(f"{d / 'time.csv'}: row {k} is not {DT} s after the previous one")
    for a in (x, u, t):
        a.setflags(write=False)
    return Run(index, d, t, x[:, :6], x[:, 6:], u)


def read_runs(root, runs) -> list:
    """:func:`read_run` for each run number (``runs``: list or range spec string; ``root=None``:
    the shipped recordings, :data:`RECORDINGS_DIR`)."""
    root = recordings_dir(root)
    if isinstance(runs, str):
        runs = parse_runs(runs)
    return [read_run(root, i) for i in runs]


# --------------------------------------------------------------------------- identification

@dataclass(frozen=True)
class Preprocessing:
    """How identification samples are made from a run (see the module docstring).

    The defaults were chosen on the training runs only (fit 1-56, validate 57-70, RMS
    against the raw logged torque) over ``cutoff_hz`` in {5, 10, 20} and ``lag`` in
    {0, 2, 3}; lag 3 matches the paper's plant (torque of tick k acts during [k+1, k+2),
    seen one sample later), see docs/robot.md.

    Attributes
    ----------
    cutoff_hz : float
        Butterworth cut-off of the zero-phase filter on velocities and torques.
    order : int
        Filter order.
    lag : int
        The logged torque of row k is paired with motion sample ``k + lag``.
    trim : int
        Samples dropped at both ends of each run (filter transients).
    stride : int
        Keep every ``stride``-th sample.
    """

    cutoff_hz: float = 5.0
    order: int = 4
    lag: int = 3
    trim: int = 10
    stride: int = 1


def _lowpass(x, prep: Preprocessing):
    from scipy.signal import butter, filtfilt  # lazy: scipy.signal's start-up (issue 38.1)
    b, a = butter(prep.order, prep.cutoff_hz / (0.5 / DT))
    return filtfilt(b, a, x, axis=0)


def identification_samples(run: Run, prep: Preprocessing = Preprocessing()):
    """Samples ``(Q, QD, QDD, U_filtered, U_raw)`` of one run, each (K, 6)."""
    N = run.n_samples
    pad = 3 * (prep.order + 1)
    if N <= 2 * prep.trim + prep.lag + pad:
        return tuple(np.zeros((0, 6)) for _ in range(5))
    qd_f = _lowpass(run.qd, prep)
    qdd = np.gradient(qd_f, DT, axis=0)
    u_f = _lowpass(run.tau, prep)
    k = np.arange(prep.trim, N - 1 - prep.trim - prep.lag)[::prep.stride]
    return run.q[k + prep.lag], qd_f[k + prep.lag], qdd[k + prep.lag], u_f[k], run.tau[k]


def stacked_samples(runs, prep: Preprocessing = Preprocessing()):
    """:func:`identification_samples` of several runs, concatenated."""
    parts = [identification_samples(r, prep) for r in runs]
    return tuple(np.vstack([p[i] for p in parts]) for i in range(5))


@dataclass(frozen=True)
class NominalFit:
    """Result of :func:`fit_nominal`: the identified model and the placeholder baseline."""

    identified: Identification
    placeholder: Identification
    runs: tuple
    prep: Preprocessing
    samples: int
    min_mass_eigenvalue: float
    settings: dict = field(default_factory=dict)


def fit_nominal(root, runs, prep: Preprocessing = Preprocessing(), prior=None,
                method: str = "lmi", prior_weight: float = 1e-3,
                scale_weight: float = 1.0) -> NominalFit:
    """Identify the nominal LWA-4P model on ``runs`` (never pass held-out runs here).

    Parameters
    ----------
    root : path
        Data directory.
    runs : list of int or str
        Runs to fit on (e.g. ``"train"``; never held-out runs).
    prep : Preprocessing
    prior : RobotModel, optional
        Prior / placeholder model (default: the shipped URDF).
    method, prior_weight, scale_weight
        See :func:`reachset_ros.robot.inertial_id.identify_inertial`.
    """
    recs = read_runs(root, runs)
    prior = prior or load_model()
    data = create_data(prior)
    Q, QD, QDD, U, _ = stacked_samples(recs, prep)
    gram = torque_gram(prior, data, Q, QD, QDD, U)
    base = BaseParameters.from_model(prior)
    ident = identify_inertial(prior, gram, method=method, prior_weight=prior_weight,
                              scale_weight=scale_weight, base=base)
    ph = identify_inertial(prior, gram, method="placeholder", base=base)
    mdata = create_data(ident.model)
    mineig = min_mass_eigenvalue(ident.model, mdata, Q[::10])
    if not mineig > 0:
        raise ReachsetError(f"identified mass matrix is not positive definite (min eigenvalue "
                            f"{mineig:.3g}); use --method lmi")
    return NominalFit(ident, ph, tuple(r.index for r in recs), prep, len(Q), mineig,
                      {"method": method, "prior_weight": prior_weight,
                       "scale_weight": scale_weight})


def torque_rms(model: RobotModel, runs, prep: Preprocessing = Preprocessing()) -> dict:
    """RMS error per joint of the logged torques predicted by ``model`` on ``runs``.

    Returns ``{"filtered": [...], "raw": [...], "samples": K}``: against the low-pass
    filtered logged torque (the fitting target) and against the raw logged torque.
    """
    Q, QD, QDD, Uf, Ur = stacked_samples(runs, prep)
    pred = predict_logged(model, create_data(model), Q, QD, QDD)
    return {"filtered": np.sqrt(np.mean((pred - Uf) ** 2, axis=0)).tolist(),
            "raw": np.sqrt(np.mean((pred - Ur) ** 2, axis=0)).tolist(),
            "samples": int(len(Q))}


def nominal_document(fit: NominalFit, command: str, data_dir: str) -> dict:
    """The YAML document of a fit: :func:`reachset_ros.robot.model_params_dict` plus
    provenance (the command that produced it), base parameters and fit statistics."""
    ident = fit.identified
    doc = {"description": "Nominal Schunk LWA-4P model identified from the real recordings "
                          "(data/lwa4p_iros2018); inertias, armature, friction and the torque "
                          "scale (N m per logged unit) are identified, kinematics from the URDF.",
           "command": command,
           "data": {"dir": data_dir, "runs": _runs_spec(fit.runs), "samples": fit.samples},
           "source": f"reachset fit-lwa4p ({ident.method}), runs {_runs_spec(fit.runs)}",
           "prior_urdf": "reachset_ros/data/lwa4p.urdf",
           "method": ident.method,
           "preprocessing": asdict(fit.prep),
           "settings": {k: v for k, v in ident.settings.items()
                        if k in ("prior_weight", "scale_weight", "min_armature", "iterations",
                                 "converged")}}
    doc.update(model_params_dict(ident.model))
    doc["base_parameters"] = {"names": list(ident.base.names),
                              "values": [float(x) for x in ident.beta]}
    doc["fit"] = {"rms_logged": [float(x) for x in ident.rms],
                  "placeholder_rms_logged": [float(x) for x in fit.placeholder.rms],
                  "placeholder_torque_scale": [float(x) for x in fit.placeholder.torque_scale],
                  "min_mass_eigenvalue": float(fit.min_mass_eigenvalue)}
    return doc


def _runs_spec(runs) -> str:
    """Compact range spec of run numbers ([1, 2, 3, 5] -> "1-3,5")."""
    runs = sorted(runs)
    out, a, prev = [], runs[0], runs[0]
    for cur in runs[1:] + [None]:
        if cur is None or cur != prev + 1:
            out.append(f"{a}-{prev}" if prev != a else f"{a}")
            a = cur
        prev = cur
    return ",".join(out)


def write_yaml_atomic(path, doc: dict, header: str = "") -> None:
    """Write ``doc`` as YAML to a new file ``path`` atomically (:func:`reachset_ros.atomic.write_yaml`)."""
    path = Path(path)
    if path.exists():
        raise ReachsetError(f"{path}: output file already exists")
    if not path.parent.is_dir():
        raise ReachsetError(f"{path.parent}: output directory not found")
    write_yaml(path, doc, header, default_flow_style=None, width=100)


def default_nominal_path() -> Path:
    """The shipped ``config/lwa4p_nominal.yaml`` (source checkout, or installed share/)."""
    here = Path(__file__).resolve().parents[2] / "config" / NOMINAL_FILE
    if here.is_file():
        return here
    try:
        from ament_index_python.packages import get_package_share_directory  # optional: only in a ROS install
        p = Path(get_package_share_directory("reachset_ros")) / "config" / NOMINAL_FILE
        if p.is_file():
            return p
    except Exception:  # noqa: BLE001  (not installed with ament)
        pass
    return here


def load_nominal(path=None) -> RobotModel:
    """The identified nominal model (default: the shipped :func:`default_nominal_path`)."""
    path = Path(path) if path is not None else default_nominal_path()
    if not path.is_file():
        raise ReachsetError(f"{path}: nominal model not found (run reachset fit-lwa4p)")
    return load_model(params=path)


# --------------------------------------------------------------------------- bag import

def run_start_stamps(runs, start_ns: int = DEFAULT_START_NS, gap_ns: int = DEFAULT_GAP_NS):
    """Stamp [ns] of the first sample of each run: each run starts ``gap_ns`` after the
    previous run's last sample. Sample k of a run has ``start + round(t_k * 1e9)``."""
    starts, cur = [], int(start_ns)
    for r in runs:
        starts.append(cur)
        cur = cur + int(round((r.t[-1] - r.t[0]) * 1e9)) + int(gap_ns)
    return starts


def plant_inputs(model: RobotModel, run: Run, data=None) -> np.ndarray:
    """``u_p[k] = M_hat(q_k)^-1 (s * tau_k - psi_hat(q_k, qd_k))`` for k < N-1 (paper eq. 6
    inverted, with the measured q, qd of tick k, as the controller computes it): the one
    implementation :func:`reachset_ros.robot.effort.plant_inputs`, which ``--input effort``
    uses on any arm's ``/joint_states``."""
    m = len(run.tau)
    return effort_plant_inputs(model, run.q[:m], run.qd[:m], run.tau, data)


def import_runs(root, runs, out, model: RobotModel | None = None,
                start_ns: int = DEFAULT_START_NS, gap_ns: int = DEFAULT_GAP_NS,
                storage: str = "mcap") -> dict:
    """Write the recordings ``runs`` to the rosbag2 bag ``out`` (atomically).

    Per sample k of a run (stamp ``start + round(t_k 1e9)``, receive time = stamp):

    * ``/joint_states``: ``position`` q_k, ``velocity`` qd_k, ``effort`` the logged torque
      of row k *as logged* (units unknown; ``torque_scale`` in the model converts to N m);
    * ``/plant_input``: ``acceleration`` u_p[k] (:func:`plant_inputs`), same stamp.

    The last sample of a run has no logged torque (input.csv has N-1 rows): it is written
    to ``/joint_states`` with an empty ``effort`` and gets no ``/plant_input``; consumers
    pairing by stamp see the run end there. Runs are separated by ``gap_ns`` of silence.

    Returns a summary ``{"runs", "samples", "plant_inputs", "first_stamp_ns",
    "last_stamp_ns"}``.
    """
    out = Path(out)
    if out.exists():
        raise ReachsetError(f"{out}: output bag already exists")
    if not out.parent.is_dir():
        raise ReachsetError(f"{out.parent}: output directory not found")
    recs = read_runs(root, runs)
    model = model or load_nominal()
    names = list(model.joint_names)
    data = create_data(model)
    starts = run_start_stamps(recs, start_ns, gap_ns)
    n_js = n_pi = 0
    last = None
    with BagWriter(out, storage=storage) as bag:
        for r, s0 in zip(recs, starts):
            up = plant_inputs(model, r, data)
            if not np.all(np.isfinite(up)):
                raise ReachsetError(f"{r.path / 'input.csv'}: non-finite plant input")
            stamps = s0 + np.round((r.t - r.t[0]) * 1e9).astype(np.int64)
            for k, st in enumerate(stamps):
                st = int(st)
                eff = r.tau[k] if k < len(r.tau) else ()
                bag.write(JOINT_STATES, joint_state(st, names, r.q[k], r.qd[k], eff), st)
                n_js += 1
                if k < len(up):
                    bag.write(PLANT_INPUT, plant_input(st, names, up[k]), st)
                    n_pi += 1
            last = int(stamps[-1])
    return {"runs": [r.index for r in recs], "samples": n_js, "plant_inputs": n_pi,
            "first_stamp_ns": int(starts[0]), "last_stamp_ns": last, "bag": str(out)}
