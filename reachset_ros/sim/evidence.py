"""The fault campaign's safety evidence sheet (issue 35.6): ``evidence.json`` and a page.

Pure data, no ROS: :func:`evidence` turns the campaign's outcomes
(:class:`~reachset_ros.sim.campaign.Outcome`, as ``campaign.json`` holds them and
``benchmarks/fault_campaign.py --rescore`` rebuilds them) into

* the **detection rate per fault class** (the classes of the score's latency rows: each
  simulator fault, ``kill``, ``stamp_jump``, ``link loss``) with the exact one-sided
  Clopper-Pearson upper bound on the miss probability (:func:`miss_upper_bound`; 0 misses in
  n: ``1 - 0.05^(1/n)`` at 95 %);
* the **response times** as quantiles (:func:`quantiles`): the fault's stamp to the stop's
  stamp (the first measurement the monitor judged non-conformant, or the tick a data rule's
  allowance ran out), the stop's stamp to the brake (the controller's first braking
  measurement, an upper bound on the stop's arrival there) and the two together;
* **stop time and distance** of every stop judged from the recorded bag
  (:func:`~reachset_ros.sim.campaign.judge_rest`) against the stop's stated bound
  (:data:`~reachset_ros.sim.safe_stop.REST_WITHIN_S`,
  :data:`~reachset_ros.sim.safe_stop.TRAVEL_WITHIN_RAD`), with an **alarm** on a stop that
  took longer or travelled further (brakes degrading);
* **false stops per fault-free hour** with the exact one-sided Poisson upper bound
  (:func:`rate_upper_bound`);
* the **stop category** (IEC 60204-1) and the response time as an **ISO 13855
  separation-distance equivalent**: ``S = K T`` with ``K = 2000 mm/s``, i.e. 2 mm per ms of
  response time (:func:`iso13855_mm`; a conversion, not a safety distance: the standard's
  ``T`` also holds the machine's stopping time, listed beside it).

:func:`page` renders the dict as one self-contained HTML page (inline style, no script, no
link); :func:`write` puts ``evidence.json`` and ``evidence.html`` in a directory.
"""
from __future__ import annotations

import html
import json
import math
from pathlib import Path

import numpy as np

from ..systems.stopping import StopPolicy
from . import campaign as cp
from .safe_stop import REST_WITHIN_S, TRAVEL_WITHIN_RAD

__all__ = ["CONFIDENCE", "K_MM_PER_S", "miss_upper_bound", "rate_upper_bound", "quantiles", "iso13855_mm",
           "fault_class", "detection", "response_times", "stops_against_bound", "false_stop_rate", "evidence",
           "page", "write"]

#: confidence of the upper bounds
CONFIDENCE = 0.95
#: ISO 13855's approach speed of a hand or arm, mm/s (2 mm per ms of response time)
K_MM_PER_S = 2000.0


def miss_upper_bound(misses, n, confidence=CONFIDENCE):
    """Exact one-sided Clopper-Pearson upper bound on a miss probability: the p with
    ``P(X <= misses | n, p) = 1 - confidence`` (the ``confidence`` quantile of
    Beta(misses + 1, n - misses)); 0 misses: ``1 - (1 - confidence)^(1/n)``. None when n = 0."""
    misses, n = int(misses), int(n)
    if n <= 0:
        return None
    if misses >= n:
        return 1.0
    if misses == 0:
        return 1.0 - (1.0 - confidence) ** (1.0 / n)
    from scipy.stats import beta  # lazy: scipy.stats costs 0.4 s of start-up (issue 38.1)
    return float(beta.ppf(confidence, misses + 1, n - misses))


def rate_upper_bound(count, exposure, confidence=CONFIDENCE):
    """Exact one-sided upper bound on a Poisson rate (``count`` events in ``exposure``, per
    unit of exposure): ``chi2(confidence, 2 (count + 1)) / 2 / exposure``; 0 events:
    ``-ln(1 - confidence) / exposure``. None without exposure."""
    if not exposure or exposure <= 0:
        return None
    from scipy.stats import chi2  # lazy (issue 38.1)
    return float(chi2.ppf(confidence, 2 * (int(count) + 1)) / 2.0 / exposure)


def quantiles(x):
    """``{"n", "p50", "p90", "p99", "max"}`` of ``x`` (numpy's linear interpolation; None if empty)."""
    x = [float(v) for v in x]
    if not x:
        return {"n": 0, "p50": None, "p90": None, "p99": None, "max": None}
    a = np.asarray(x)
    return {"n": len(x), **{f"p{p}": float(np.percentile(a, p)) for p in (50, 90, 99)}, "max": float(a.max())}


def iso13855_mm(ms):
    """The ISO 13855 separation-distance equivalent of a time: ``S = K T``, K = 2000 mm/s."""
    return None if ms is None else K_MM_PER_S * ms * 1e-3


def fault_class(event):
    """The class an event's detection counts in: the simulator fault, ``link <fault>``, or the kind."""
    return (event.fault if event.kind == "sim" else
            f"link {event.fault}" if event.kind == "link" else event.kind)


def _must_stop(outcomes):
    return [o for o in outcomes if o.event.expect == "stop"]


def detection(outcomes, confidence=CONFIDENCE):
    """Per fault class ``{n, stopped, missed, unobservable, rate, miss_upper_bound}``, counted
    by :func:`~reachset_ros.sim.campaign.score` on that class' outcomes (so they sum to the
    campaign's score)."""
    by = {}
    for o in _must_stop(outcomes):
        by.setdefault(fault_class(o.event), []).append(o)
    out = {}
    for k, os_ in sorted(by.items()):
        s = cp.score(os_)
        n = s["faults_injected"]
        out[k] = {"n": n, "stopped": s["stops"], "missed": s["missed_stops"], "unobservable": len(s["unobservable"]),
                  "rate": s["stops"] / n if n else None,
                  "miss_upper_bound": miss_upper_bound(s["missed_stops"], n, confidence)}
    return out


def response_times(outcomes):
    """Quantiles (ms) of fault stamp -> stop stamp (``detect``), stop stamp -> brake
    (``brake``) and fault stamp -> brake (``total``) of every fault that stopped; the brake
    is measured only where the controller that had the stop acts on it (``unmeasured``: the
    others, e.g. a killed controller, braked by the drives' watchdog)."""
    arrived = [o for o in _must_stop(outcomes) if o.stops and not o.note.startswith("unobservable")]
    detect = [(o.evidence_from() - o.latency_from()) * 1e-6 for o in arrived]
    acting = [o for o in arrived if cp.controller_acts(o.event) and o.controller_ns]
    brake = [(o.controller_ns - o.evidence_from()) * 1e-6 for o in acting]
    total = [(o.controller_ns - o.latency_from()) * 1e-6 for o in acting]
    return {"detect_ms": quantiles(detect), "brake_ms": quantiles(brake), "total_ms": quantiles(total),
            "unmeasured": [o.event.label() for o in arrived if o not in acting]}


def stops_against_bound(outcomes, rest_within_s=REST_WITHIN_S, travel_within_rad=TRAVEL_WITHIN_RAD):
    """Every stop judged from the bag: its time to rest and travel against the bound, and an
    ``alarm`` when it took longer, travelled further, or did not come to rest."""
    rows = []
    for o in outcomes:
        r = o.rest
        if not o.stops or r is None or r.get("ok") is None:
            continue
        rest_s, travel = r.get("rest_s"), r.get("travel_rad")
        why = []
        if rest_s is None:
            why.append("not at rest")
        elif rest_s > rest_within_s:
            why.append(f"rest after {rest_s:.3f} s > {rest_within_s:g} s")
        if travel is not None and travel > travel_within_rad:
            why.append(f"travel {travel:.4f} rad > {travel_within_rad:g} rad")
        if not r["ok"] and not why:
            why.append(r.get("why") or "judged not at rest")
        rows.append({"event": o.event.label(), "stop_ns": int(o.stops[0][0]), "rest_s": rest_s, "travel_rad": travel,
                     "alarm": bool(why), "why": "; ".join(why)})
    return {"rest_within_s": rest_within_s, "travel_within_rad": travel_within_rad, "stops": rows,
            "alarms": sum(r["alarm"] for r in rows),
            "rest_s": quantiles([r["rest_s"] for r in rows if r["rest_s"] is not None]),
            "travel_rad": quantiles([r["travel_rad"] for r in rows if r["travel_rad"] is not None])}


def false_stop_rate(score, confidence=CONFIDENCE):
    """False stops per fault-free (monitored, simulated) hour and its upper bound."""
    hours = score["fault_free_minutes"] / 60.0
    n = score["false_stops"]
    return {"false_stops": n, "fault_free_hours": hours, "per_hour": n / hours if hours > 0 else None,
            "per_hour_upper_bound": rate_upper_bound(n, hours, confidence)}


def evidence(outcomes, *, info=None, apparatus_stops=(), stop_category=None, confidence=CONFIDENCE):
    """The evidence sheet of a campaign's outcomes (module docstring) as a JSON-able dict.

    ``stop_category``: the controller's (None: ``info["stop_category"]``, else the
    controller node's default, :class:`~reachset_ros.systems.stopping.StopPolicy`'s)."""
    info = dict(info or {})
    score = cp.score(outcomes, apparatus_stops)
    cat = stop_category if stop_category is not None else info.get("stop_category", StopPolicy().category)
    resp = response_times(outcomes)
    total = resp["total_ms"]
    iso = {k: iso13855_mm(total[k]) for k in ("p50", "p99", "max")}
    stops = stops_against_bound(outcomes)
    with_stop = None if total["max"] is None or stops["rest_s"]["max"] is None else iso13855_mm(
        total["max"] + 1e3 * stops["rest_s"]["max"])
    return {
        "confidence": confidence,
        "campaign": {k: info[k] for k in ("seed", "model", "inflation", "calibrated_inflation", "workdir")
                     if k in info},
        "score": {k: score[k] for k in ("events", "faults_injected", "stops", "missed_stops", "false_stops",
                                        "fault_free_minutes")},
        "detection": detection(outcomes, confidence),
        "miss_upper_bound": miss_upper_bound(score["missed_stops"], score["faults_injected"], confidence),
        "response": resp,
        "stops": stops,
        "false_stops": false_stop_rate(score, confidence),
        "stop_category": int(cat),
        "iso13855": {"K_mm_per_s": K_MM_PER_S, "mm_per_ms": K_MM_PER_S * 1e-3, "response_mm": iso,
                     "response_and_rest_max_mm": with_stop,
                     "note": "S = K T with K = 2000 mm/s: 2 mm per ms of the fault->brake response time; a "
                             "conversion, not a safety distance (T also holds the stopping time: the slowest rest "
                             "is added in response_and_rest_max_mm)"},
    }


def _f(x, fmt="{:.3g}"):
    return "-" if x is None else (fmt.format(x) if isinstance(x, (int, float)) and math.isfinite(x) else str(x))


def _table(head, rows):
    h = "".join(f"<th>{html.escape(str(c))}</th>" for c in head)
    body = "".join("<tr" + (' class="alarm"' if alarm else "") + ">" + "".join(
        f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r, alarm in rows)
    return f"<table><tr>{h}</tr>{body}</table>"


def _q_row(name, q, mm=False):
    cells = [name, q["n"]] + [_f(q[k], "{:.1f}") for k in ("p50", "p90", "p99", "max")]
    if mm:
        cells += [_f(iso13855_mm(q[k]), "{:.0f}") for k in ("p99", "max")]
    return cells, False


def page(ev):
    """One self-contained HTML page of an :func:`evidence` dict (no script, no external link)."""
    c = int(round(100 * ev["confidence"]))
    s, fs, st, r = ev["score"], ev["false_stops"], ev["stops"], ev["response"]
    det = [([k, v["n"], v["stopped"], v["missed"], _f(v["rate"], "{:.1%}"), _f(v["miss_upper_bound"], "{:.3f}")],
            bool(v["missed"])) for k, v in ev["detection"].items()]
    det.append((["all", s["faults_injected"], s["stops"], s["missed_stops"],
                 _f(s["stops"] / s["faults_injected"] if s["faults_injected"] else None, "{:.1%}"),
                 _f(ev["miss_upper_bound"], "{:.3f}")], bool(s["missed_stops"])))
    stops = [([x["event"], _f(x["rest_s"], "{:.3f}"), _f(x["travel_rad"], "{:.4f}"), "ALARM: " + x["why"]
               if x["alarm"] else "ok"], x["alarm"]) for x in st["stops"]]
    iso = ev["iso13855"]
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>Safety evidence</title><style>",
        "body{font-family:sans-serif;margin:2em;max-width:70em}table{border-collapse:collapse;margin:1em 0}"
        "td,th{border:1px solid #999;padding:.2em .6em;text-align:right}td:first-child{text-align:left}"
        "tr.alarm{background:#fdd}.bad{color:#b00;font-weight:bold}",
        "</style></head><body><h1>Safety evidence of a fault campaign</h1>",
        "<p>Campaign: " + html.escape(", ".join(f"{k} {v}" for k, v in ev["campaign"].items()) or "-") + "</p>",
        f"<p>Stop category (IEC 60204-1): <b>{ev['stop_category']}</b>. Events {s['events']}, faults that must "
        f"stop {s['faults_injected']}, stopped {s['stops']}, missed "
        f"<span class='{'bad' if s['missed_stops'] else ''}'>{s['missed_stops']}</span>.</p>",
        f"<h2>Detection per fault class</h2><p>Upper bound on the miss probability: exact one-sided "
        f"Clopper-Pearson at {c} % (0 misses in n: 1 - {1 - ev['confidence']:.2f}^(1/n)).</p>",
        _table(["class", "n", "stopped", "missed", "detection rate", f"miss probability, {c} % upper bound"], det),
        "<h2>Response times, ms</h2><p>fault stamp &rarr; stop stamp (the first non-conformant measurement or "
        "the tick a data rule ran out) &rarr; brake (the controller's first braking measurement). ISO 13855 "
        f"separation-distance equivalent: S = K T, K = {iso['K_mm_per_s']:.0f} mm/s, i.e. "
        f"{iso['mm_per_ms']:g} mm per ms (a conversion).</p>",
        _table(["segment", "n", "p50", "p90", "p99", "max", "p99 as mm", "max as mm"],
               [_q_row("fault → stop stamp", r["detect_ms"], True),
                _q_row("stop stamp → brake", r["brake_ms"], True), _q_row("fault → brake", r["total_ms"], True)]),
        f"<p>Not measured to the brake (the drives' watchdog brakes): {html.escape(', '.join(r['unmeasured']) or '-')}."
        f" Fault &rarr; brake (max) plus the slowest rest as distance: {_f(iso['response_and_rest_max_mm'], '{:.0f}')}"
        " mm.</p>",
        f"<h2>Stops against their bound</h2><p>Bound: at rest within {st['rest_within_s']:g} s, travel at most "
        f"{st['travel_within_rad']:g} rad. Alarms: <span class='{'bad' if st['alarms'] else ''}'>{st['alarms']}"
        "</span>.</p>",
        _table(["event", "rest, s", "travel, rad", "verdict"], stops),
        f"<h2>False stops</h2><p>{fs['false_stops']} in {fs['fault_free_hours']:.3f} fault-free h: "
        f"{_f(fs['per_hour'])} per h, {c} % upper bound {_f(fs['per_hour_upper_bound'])} per h.</p>",
        "</body></html>"]
    return "\n".join(parts)


def write(ev, directory):
    """``evidence.json`` and ``evidence.html`` of ``ev`` in ``directory``; returns both paths."""
    d = Path(directory)
    js, pg = d / "evidence.json", d / "evidence.html"
    js.write_text(json.dumps(ev, indent=1))
    pg.write_text(page(ev))
    return js, pg
