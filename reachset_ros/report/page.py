"""The report as one self-contained HTML page: inline CSS, figures as base64 PNG, no script,
no link to anything outside the file (it opens offline, in any browser).

Sections: the verdict and the bags; the guarantee table (per joint: inflation, R*_e, R*_u
against U_p, the certificate; the model's provenance); then one ``<section id="joint-NAME">``
per joint with its figures (deviations against R_a, set use over time) and its violations and
stops in seconds from each bag's start.
"""
from __future__ import annotations

import base64
import html
from pathlib import Path

from .figures import deviations_png, set_use_png

__all__ = ["render"]

_CSS = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 70em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; border-bottom: 1px solid #bbb; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.5em; text-align: left; vertical-align: top; }
th { background: #eee; } .bad { color: #b00; font-weight: bold; } .ok { color: #070; font-weight: bold; }
img { max-width: 100%; display: block; margin: 0.5em 0; } code { font-size: 0.9em; }
"""

#: most violations listed per joint and bag (all are counted)
MOST_LISTED = 50


def _e(x):
    return html.escape(str(x))


def _img(png, alt):
    return f"<img alt='{_e(alt)}' src='data:image/png;base64,{base64.b64encode(png).decode('ascii')}'>"


def _table(head, rows):
    h = "".join(f"<th>{_e(c)}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{h}</tr>{body}</table>"


def _fmt(v, spec=".4g"):
    return "&ndash;" if v is None else _e(format(v, spec))


def _interval(v):
    return "&ndash;" if v is None else f"[{_fmt(v[0])}, {_fmt(v[1])}]"


def _guarantee(rep):
    rows = []
    for n in rep.joints:
        g = rep.guarantee[n]
        cert = ("&ndash;" if g["certified"] is None else
                "<span class='ok'>R*_u &sube; U_p</span>" if g["certified"] else "<span class='bad'>NOT certified</span>")
        rows.append([_e(n), _fmt(g["inflation"]), _e(g["gains"]) if g["gains"] else "&ndash;",
                     "&ndash;" if g["re_radius"] is None else
                     f"&plusmn;{_fmt(g['re_radius'][0])} rad, &plusmn;{_fmt(g['re_radius'][1])} rad/s "
                     f"(&Vert;R*_e&Vert; {_fmt(g['re_norm'])})",
                     _interval(g["ru"]), "&ndash;" if g["u_max"] is None else f"&plusmn;{_fmt(g['u_max'])}",
                     cert + (f"<br>{_e(g['reason'])}" if g["reason"] else "")])
    table = _table(["joint", "inflation", "gains", "R*_e (synthesis, radius)", "R*_u [rad/s^2] (checked sets)",
                    "U_p [rad/s^2]", "certificate"], rows)
    prov = rep.model.provenance or {}
    cal = rep.model.calibration or {}
    bags = prov.get("bags") or []
    items = [("model id (SHA-256 prefix, as /conformance/status model_id)", f"<code>{_e(rep.model_id)}</code>"),
             ("model file", f"<code>{_e(rep.model_path)}</code>"),
             ("made by", f"<code>{_e(prov.get('command', '-'))}</code>"),
             ("created", _e(prov.get("created", "-"))),
             ("from bags", "<br>".join(f"<code>{_e(b.get('path'))}</code> sha256 {_e(str(b.get('sha256'))[:12])}"
                                       for b in bags) or "-"),
             ("inflation", _e(f"calibrated ({cal.get('method')})" if cal else "given, not calibrated")),
             ("horizon k*", _e(rep.model.horizon)), ("estimator", _e(rep.model.estimator.name)),
             ("this report", f"<code>{_e(rep.command or '-')}</code>")]
    return ("<h2 id='guarantee'>Guarantee</h2>" + table
            + "<p>R*_u is certified by the gate the nodes run (<code>systems.gains.certify</code>, the joint's own "
              "inflation, the model's recorded U_e,ff); R*_e as the synthesis recorded it.</p>"
            + _table(["provenance", ""], [[_e(k), v] for k, v in items]))


def _events_table(rep):
    rows = [[f"<code>{_e(Path(r.path).name)}</code>", _e(e.kind), _fmt(e.t_s, ".3f"), _e(e.stamp_ns), _e(e.joint or "-"),
             _e(e.reason or "-")] for r in rep.runs for e in r.events]
    if not rows:
        return "<p>No safe stop, reset or fault onset recorded in the bags (no <code>/safe_stop</code> message).</p>"
    return _table(["bag", "event", "t [s from the bag's start]", "stamp [ns]", "joint", "reason"], rows)


def _joint_section(rep, name):
    s = rep.summary()["joints"][name]
    verdict = ("<span class='ok'>conformant</span>" if s["violations"] == 0 else
               f"<span class='bad'>NOT conformant: {s['violations']} violating ticks</span>")
    rows = []
    for r in rep.runs:
        j = r.joints.get(name)
        if j is None:
            continue
        vt = j.violation_times()
        listed = ", ".join(f"{t:.3f}" for t in vt[:MOST_LISTED]) + (f" ... ({len(vt)} in all)" if len(vt) > MOST_LISTED
                                                                      else "")
        stops = ", ".join(f"{e.t_s:.3f}" for e in r.events if e.kind == "stop" and e.joint in ("", name))
        rows.append([f"<code>{_e(Path(r.path).name)}</code>", _e(j.test_cases), _e(j.violations), _e(listed or "-"),
                     _e(stops or "-")])
    use = s["largest_set_use"]
    return (f"<section id='joint-{_e(name)}' class='joint'><h2>{_e(name)}</h2>"
            f"<p>{verdict}; largest set use {_fmt(use, '.3f')}; {s['test_cases']} test cases; checked with inflation "
            f"{_fmt(rep.guarantee[name]['inflation'])}.</p>"
            + _table(["bag", "test cases", "violating ticks", "violations [s from the bag's start]",
                      "stops of this joint [s]"], rows)
            + "<h3>Measured deviations against the reachable sets R_a[k]</h3>"
            + _img(deviations_png(name, rep.model, rep.thm, rep.devs[name]), f"{name}: deviations against R_a")
            + "<h3>Set use over time</h3>"
            + _img(set_use_png(name, rep.runs), f"{name}: set use over time") + "</section>")


def render(rep):
    """The page of a :class:`~reachset_ros.report.build.ReportData`, as a string."""
    s = rep.summary()
    verdict = ("<p class='ok'>conformant: no tick of any joint left its reachable set</p>" if s["conformant"] else
               "<p class='bad'>NOT conformant: " + _e(", ".join(f"{n} {j['violations']} ticks" for n, j in
                                                               s["joints"].items() if j["violations"])) + "</p>")
    bags = _table(["bag", "start (first /joint_states stamp) [ns]", "joints", "stops"],
                  [[f"<code>{_e(r.path)}</code>", _e(r.start_ns), _e(", ".join(r.joints)),
                    _e(sum(e.kind == "stop" for e in r.events))] for r in rep.runs])
    nav = " &middot; ".join(f"<a href='#joint-{_e(n)}'>{_e(n)}</a>" for n in rep.joints)
    parts = ["<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
             f"<title>reachset report: {_e(rep.model_id)}</title><style>{_CSS}</style></head><body>",
             "<h1>Reachset conformance report</h1>", verdict, bags,
             f"<p>Joints: {nav} &middot; <a href='#guarantee'>guarantee</a></p>",
             "<h2>Safe stops and faults</h2>", _events_table(rep), _guarantee(rep)]
    parts += [_joint_section(rep, n) for n in rep.joints]
    parts.append("</body></html>\n")
    return "".join(parts)
