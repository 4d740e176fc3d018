"""Controller synthesis and re-identification from bags (paper eq. 10; Sec. III-D, step 3):
the workflow of ``reachset synthesize`` and of the synthesis node's worker.

:func:`synthesize` plans the synthesis (:func:`reachset_ros.synthesis.pipeline.plan`), reads
the bags in this process or sweeps them on a fleet (:mod:`reachset_ros.fleet`: the choice is
made here, the synthesis package never imports the fleet), solves
(:func:`reachset_ros.synthesis.pipeline.solve`), then writes the optional figures and the model
file, and returns a :class:`SynthesisResult` whose :meth:`~SynthesisResult.to_json` is the
command's ``--json`` object (without ``seconds``). Mode ``reidentify`` (the controller of
``options.model`` kept, only the sets re-identified) is the same workflow with
``SynthesisOptions(mode="reidentify", model=...)``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from .. import fleet as fl
from .. import guarantees
from ..bags import read_estimates, read_joint_series
from ..conformance import model as mdl
from ..conformance.envelope import ClassBounds, unvalidated
from ..bags.messages import JOINT_STATES, PLANT_INPUT
from ..errors import ReachsetError, first_line
from ..synthesis.pipeline import BagData, BagSynthesis, SynthesisOptions, plan, read_bags, solve

_TOPICS = (JOINT_STATES, PLANT_INPUT)

__all__ = ["SynthesisOptions", "SynthesisResult", "synthesize", "sweep_on_fleet"]


@dataclass(frozen=True, kw_only=True)
class SynthesisResult:
    """What :func:`synthesize` computed and wrote.

    Attributes
    ----------
    synthesis : BagSynthesis
        The per-joint results and problems, the model (:meth:`BagSynthesis.model`).
    model : str or None
        The model file written.
    plots : list of str or None
        The figures written (None: none asked for).
    """

    synthesis: BagSynthesis
    model: str | None = None
    plots: list | None = None
    calibration: dict | None = None
    envelope: dict | None = None      # the envelope the model records and the class checked against it

    def to_json(self):
        """The ``reachset synthesize --json`` object, without ``seconds``."""
        out = self.synthesis.as_dict()
        if self.plots is not None:
            out["plots"] = list(self.plots)
        if self.calibration is not None:
            out["calibration"] = self.calibration
        if self.envelope is not None:
            out["envelope"] = self.envelope
        if self.model is not None:
            out["model"] = self.model
        return out


def sweep_on_fleet(pl, *, fleet, fleet_read):
    """The bags' :class:`~reachset_ros.synthesis.pipeline.BagData` from an open ``fleet``: one
    task per bag, merged exactly (the same data, to the bit, as :func:`read_bags`), and a
    checker that batch-checks a non-conformant xi on the fleet."""
    read = replace(fleet_read, joints=None if pl.names is None else tuple(pl.names), dt=pl.plant.dt)
    sweep = fl.SweepSpec(pl.plant, pl.estimator, pl.horizon, pl.thm)
    swept = fl.extremes(fleet, pl.bags, read, sweep, references=True, loops=pl.loops)
    return BagData(names=list(swept.devs), series=None, devs=swept.devs, report=swept.report,
                   references=swept.references, loops=swept.loops, sha256=swept.sha256,
                   checker=fl.Checker(fleet, pl.bags, read, sweep))


def calibrated_model(bs: BagSynthesis, model, *, folds, topics=None, reader=None):
    """``model`` (the synthesis' own) with its inflation calibrated on its sets by ``folds``-fold
    cross-validation of the bags, read as the synthesis read them (``topics``, ``reader``)
    (issue 34.11, :func:`reachset_ros.workflows.calibrate.calibrate_model`), and the ``--json``
    ``calibration`` object; ``certified`` says whether the gains' R*_u certificate (for the
    synthesis' ``inflation``) covers the calibrated inflation, joint by joint (each joint's own
    calibrated inflation against the one its R*_u was synthesised for, issue 35.1)."""
    from .calibrate import calibrate_model
    cm = calibrate_model(model, bags=list(bs.bags), folds=folds, topics=topics or _TOPICS, reader=reader)
    synthesised = {n: float(r.inflation) for n, r in bs.results.items()}
    info = {"inflation": cm.model.largest_inflation(), "inflations": cm.model.inflations(), "folds": int(folds),
            "rule": cm.rule["sets"], "per_joint": cm.model.calibration["per_joint"],
            "synthesised_for_inflation": max(synthesised.values()), "synthesised_for_inflations": synthesised,
            "certified": all(cm.model.joint_inflation(n) <= x for n, x in synthesised.items())}
    return cm.model, info


def synthesize(bags, options: SynthesisOptions, *, out=None, plot=None, command="", fleet=None, fleet_read=None,
               calibrate=None):
    """Synthesise (or re-identify) from ``bags`` (``reachset synthesize``).

    Parameters
    ----------
    bags : sequence of path
    options : SynthesisOptions
    out : path, optional
        Write the model file (sets and gains) here, once everything is computed.
    plot : path, optional
        Write PNG figures (R_e, R_u, conformance) into this directory (needs the series in this
        process: not with a fleet).
    command : str
        The command line recorded in the model's provenance.
    fleet : reachset_ros.fleet.cluster.Fleet, optional
        A fleet (not yet entered): the sweep runs one task per bag on it, read as
        ``fleet_read`` (:class:`~reachset_ros.fleet.ReadSpec`; its joints and dt are set
        here) says; the result is the single-process one to the bit (provenance aside).
    calibrate : int, optional
        K: the model's inflation is calibrated on the synthesised sets by K-fold
        cross-validation of the bags (:func:`calibrated_model`; issue 34.11), and recorded.

    Returns
    -------
    SynthesisResult
    """
    pl = plan(bags, options)
    series = None
    if fleet is None:
        data = read_bags(pl)
        bs, series = solve(pl, data), data.series
    else:
        with fleet:                 # open while the problems' checker may still need it
            bs = solve(pl, sweep_on_fleet(pl, fleet=fleet, fleet_read=fleet_read))
    env, env_json = synthesis_envelope(bs, series, options)
    plots = None
    if plot:
        from .. import plots as pp  # heavy optional dependency: matplotlib, only for --plot
        plots = []
        est_rows = read_estimates(list(bs.bags), list(bs.results))
        for pb in bs.problems:
            plots += [str(p) for p in pp.plot_joint(plot, pb, bs.results[pb.name], (est_rows or {}).get(pb.name))]
    model, calibration = None, None
    written = replace(bs.model(command), envelope=env)
    if calibrate is not None:
        written, calibration = calibrated_model(bs, written, folds=calibrate, topics=options.topics,
                                                reader=options.reader)
    if out is not None:
        mdl.save(written, out)
        model = str(out)
    return SynthesisResult(synthesis=bs, model=model, plots=plots, calibration=calibration, envelope=env_json)


def class_bounds(bs: BagSynthesis):
    """Per joint what the synthesis' reference class and certificate let it do
    (:class:`~reachset_ros.conformance.envelope.ClassBounds` fields): ``|qdd_d|`` up to the class'
    ``qdd_max`` (the given or recorded :class:`~reachset_ros.synthesis.reference_error.ReferenceClass`,
    else the recorded references' largest) and u_p over the certified R*_u (``ru``; method 2's
    ``ru_star``)."""
    out = {}
    for n, r in bs.results.items():
        ref = r.reference or {}
        source = ("the reference class' qdd_max" if ref.get("reference_class") else
                  "the recorded references' largest |qdd_d|")
        out[n] = {"qdd_max": float(ref.get("qdd_max", r.u_ff)), "qdd_source": source,
                  "u": tuple(float(x) for x in ref.get("ru_star", r.ru)), "u_source": "R*_u"}
    return out


def synthesis_envelope(bs: BagSynthesis, series, options: SynthesisOptions):
    """The validated envelope of the synthesis' data (:func:`~reachset_ros.workflows.identify.fit_envelope`,
    as ``identify`` records it: the synthesis identifies the sets from these data too) and its
    ``--json`` object: the summary, and ``unvalidated`` ({joint: [line]}) with ``note``, the
    parts of the synthesis' reference class the model was never validated on (issue 37.3,
    :func:`~reachset_ros.conformance.envelope.unvalidated`, :func:`class_bounds`).
    ``series`` None (a fleet's sweep): the bags are read here once more. Data the envelope
    cannot be fitted on (a joint with no sample of some feature): none recorded, and why."""
    from .identify import fit_envelope        # identify's imports are not needed for `synthesize --help`
    if series is None:
        series, _ = read_joint_series(list(bs.bags), list(bs.results), bs.plant.dt, options.topics or _TOPICS,
                                      **(options.reader or {}))
    try:
        env, out = fit_envelope({n: series[n] for n in bs.results}, horizon=bs.horizon)
    except ReachsetError as e:
        return None, {"recorded": False, "reason": first_line(e), "unvalidated": None,
                      "note": "envelope: none recorded"}
    notes = {n: list(v) for n, v in unvalidated(env, {n: ClassBounds(**b) for n, b in class_bounds(bs).items()}).items()}
    out.update(unvalidated=notes, note=guarantees.envelope_note(notes, "the reference class and R*_u lie"))
    return env, out

