"""The conformance report: one self-contained HTML page of bags checked against a model
(``reachset report BAG... --model M --out report.html``, issue 36.4).

* :mod:`.build`: what the page shows, computed by the core ``check`` and ``replay`` use
  (:func:`.build.build_report` -> :class:`.build.ReportData`);
* :mod:`.figures`: the figures as PNG bytes (``reachset check --plot``'s deviations against
  R_a, drawn by :func:`reachset_ros.plots.plot_deviations`; set use over time);
* :mod:`.page`: the HTML (inline CSS, base64 figures, no script, nothing fetched).

:func:`write_report` is the one entry point (the command, the demo and the fault campaign call
it); the page is written atomically (:func:`reachset_ros.atomic.write_text`). Pure: no ROS import.

May import: :mod:`reachset_ros.errors`, :mod:`reachset_ros.atomic`, :mod:`reachset_ros.defaults`,
:mod:`reachset_ros.guarantees`, :mod:`reachset_ros.sets`, :mod:`reachset_ros.systems`,
:mod:`reachset_ros.conformance`, :mod:`reachset_ros.bags`, :mod:`reachset_ros.synthesis` and
:mod:`reachset_ros.plots`; never the processes, the nodes, the workflows or the commands.
"""
from pathlib import Path

from ..atomic import write_text
from ..errors import ReachsetError
from .build import ReportData, build_report, guarantee_rows
from .page import render

__all__ = ["write_report", "build_report", "render", "ReportData", "guarantee_rows"]


def check_out(out):
    """The page's path, refused (one line) before any work when it cannot be written."""
    p = Path(out)
    if p.is_dir():
        raise ReachsetError(f"{p}: --out is a directory")
    if not p.parent.is_dir():
        raise ReachsetError(f"{p.parent}: output directory does not exist")
    return p


def write_report(bags, model, out, *, joints=None, topics=None, options=None, command="", log=None):
    """Check ``bags`` against the model file ``model`` and write the report page to ``out``.

    Parameters
    ----------
    bags : sequence of path
    model : path
        The model file.
    out : path
        The HTML page to write (atomically: nothing half-written on any error).
    joints, topics, options, command, log
        As :func:`.build.build_report` (``topics`` None: ``/joint_states`` and ``/plant_input``).

    Returns
    -------
    dict
        :meth:`ReportData.summary` with ``"report"``: the page's path.

    Raises
    ------
    ReachsetError
        Bad input (a bag, the model, the output path), one line.
    """
    p = check_out(out)
    kw = {} if topics is None else {"topics": tuple(topics)}
    rep = build_report([str(b) for b in bags], model, joints=joints, options=options, command=command, log=log, **kw)
    write_text(p, render(rep))
    return {**rep.summary(), "report": str(p)}
