"""The guarantee's assumptions, one row each, and the refusal that names the row it protects.

A guarantee of this suite ("conformant", "inside R*_e", "R*_u within U_p", "the arm is
stopped") holds only under assumptions: the paper's Theorem 1 needs a horizon of at least the
plant's minimum, the certificate ``R*_u ⊆ U_p`` needs the reference to lie in the class ``U_ff``
it was computed for, and so on. Each assumption is a row of :data:`ROWS`, with an id (``G1``,
``G2``, ...) that docs/theory.md's table "Assumptions at a glance" uses too (a test keeps the two
equal): there each row says where it is enforced (at identify, at synthesis, at the gain gate, at
start-up, every tick) and which test shows it.

Code that refuses a model, a gain change or a start-up because it would void a row raises
:func:`refused` with the row's id: the one-line message ends with ``[guarantee G7: R*_u lies
within U_p for the sets the monitor checks]``, so the user reads which promise the input would
have broken.

Syntax::

    raise guarantees.refused("G1", "horizon 0 is below the minimum horizon 2")

Pure Python, a leaf (imports only :mod:`reachset_ros.errors`).
"""
from __future__ import annotations

from .errors import ReachsetError

__all__ = ["ROWS", "GuaranteeRefused", "refused", "tag"]

#: id -> the assumption, in the words of docs/theory.md's table "Assumptions at a glance"
ROWS = {
    "G1": "k* is at least the plant's minimum horizon (every alpha in some Theorem-1 row)",
    "G2": "a test case never spans two recordings, a gap or an invalid sample",
    "G3": "the monitor checks, every tick, the test cases the model needs",
    "G4": "the loop that runs is the loop that was certified (gains, observer, law, dt)",
    "G5": "the reference lies in the class R_u is certified for (|qdd_d| <= u_ff, continuous)",
    "G6": "tracking is judged against R*_e only from zero initial error (after the transient)",
    "G7": "R*_u lies within U_p for the sets the monitor checks",
    "G8": "after a safe stop the arm is at rest",
    "G9": "a margin that is not a number fails closed",
    "G10": "R_e and R_u are outer bounds in floating point",
    "G11": "the reference error is bounded for every reference the controller accepts",
    "G12": "the arm moves only while a monitor with a model checks every input",
    "G13": "the monitor's verdicts keep up with the measurements",
    "G14": "only the audited reset clears a stop",
    "G15": "the recorded closed loop lies inside the certified R*_e",
    "G16": "controller and observer run one certified pair of gains",
    "G17": "u_p is computed online as it was for identification (source, URDF, parameters)",
    "G18": "the inflation was calibrated on the sets the monitor checks",
    "G19": "the gains that run are certified for the sets the running monitor checks",
    "G20": "the identification data cover the reference class on every joint, in calibration folds large enough "
           "to judge",
    "G21": "every tick is classified inside or outside the envelope of the identification data, and the part of "
           "the certified reference class outside it is named (an empirical record of where the data were, not a "
           "guarantee)",
    "G22": "online, the monitor says when the data are outside the envelope, and a violation's stop says whether "
           "they were inside",
}


class GuaranteeRefused(ReachsetError):
    """An input refused because it would void a row of :data:`ROWS` (``.row`` names it)."""

    def __init__(self, message: str, *, row: str):
        super().__init__(message)
        self.row = row


def tag(row: str) -> str:
    """``"[guarantee G7: R*_u lies within U_p ...]"``: the words a refusal ends with."""
    return f"[guarantee {row}: {ROWS[row]}]"


def refused(row: str, message: str) -> GuaranteeRefused:
    """The error for an input that would void row ``row``: ``message`` (one line) followed by
    :func:`tag`. Raise it where the input is refused.

    Parameters
    ----------
    row : str
        A key of :data:`ROWS` (``KeyError`` otherwise: a refusal must name a real row).
    message : str
        What was refused and why, one line.
    """
    lines = str(message).splitlines() or [""]
    lines[0] = f"{lines[0]} {tag(row)}"
    return GuaranteeRefused("\n".join(lines), row=row)


def envelope_note(notes, inside: str) -> str:
    """One line naming what :func:`~reachset_ros.conformance.envelope.unvalidated` found (row
    G21's claim, worded once), used by every caller (the gain gate's
    :meth:`~reachset_ros.systems.gains.PairCertificate.envelope_note`, ``reachset synthesize``).

    Parameters
    ----------
    notes : dict or None
        ``{joint: lines}`` from :func:`~reachset_ros.conformance.envelope.unvalidated`; None
        when the model records no envelope.
    inside : str
        What lies inside the axes when no line was found, with its verb (e.g. ``"the
        reference class and R*_u lie"``).

    Returns
    -------
    str
        ``"envelope: none recorded"``, ``"envelope: <inside> inside the validated envelope's
        axes"``, or ``"envelope: NOT VALIDATED, the model was never validated on: "``
        and the lines joined by ``"; "``.
    """
    if notes is None:
        return "envelope: none recorded"
    lines = [line for v in notes.values() for line in v]
    if not lines:
        return f"envelope: {inside} inside the validated envelope's axes"
    return "envelope: NOT VALIDATED, the model was never validated on: " + "; ".join(lines)
