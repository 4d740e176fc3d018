"""The validated envelope's representation, measured on the real LWA-4P data (issue 37).

Run: .venv/bin/python benchmarks/envelope.py [--work DIR] [--verbose]

Protocol (docs/real-data.md): the nominal model, the bags and the conformance model (with
``--calibrate 5``) are fitted on the training runs of families 1-80 (runs 1-80 not divisible by
4); the envelope candidates are fitted on the same training bag (never a held-out run). For
each candidate, per joint:

(a) of family 81-100's violating ticks (every run of it, checked against the calibrated model),
    the share that lies INSIDE the envelope (target <= 1 %): a violation inside is one the
    envelope cannot explain as "never validated";
(b) of the held-out ticks of 1-80 (runs divisible by 4), the share OUTSIDE the envelope
    (target <= 1 %): data of the validated kind called unvalidated.

Also the share of family 81-100's ticks outside (how much of the new motion is flagged). The
bags come from ``reachset`` commands (printed with ``--verbose``); ``--work DIR`` keeps and
reuses them. Prints a markdown table; the last line names the candidate ``identify`` records.
"""
import argparse
import sys
import tempfile
from pathlib import Path


REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
from reachset_ros.bags import read_joint_series  # noqa: E402
from reachset_ros.bags.messages import JOINT_STATES, PLANT_INPUT  # noqa: E402
from reachset_ros.conformance import envelope as ev  # noqa: E402
from reachset_ros.conformance import model as mdl  # noqa: E402
from reachset_ros.conformance.theorem1 import check  # noqa: E402
from reachset_ros.robot import lwa4p  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_data  # noqa: E402
from real_data import cli  # noqa: E402  (the real-data protocol's runner of reachset commands)


#: (label, bins, dilation, hold, grids)
CANDIDATES = (
    ("box (training min/max)", 1, 0, 0, ()),
    ("box widened by 1/16 of the range", 16, 1, 0, ()),
    ("box widened by 1/16, hold k*", 16, 1, 125, ()),
    ("grid 8 (q,qd)+(qd,u)", 8, 1, 0, (("q", "qd"), ("qd", "u"))),
    ("grid 16 (q,qd)+(qd,u)", 16, 1, 0, (("q", "qd"), ("qd", "u"))),
    ("grid 16 (q,qd)+(qd,u), no dilation, hold k*", 16, 0, 125, (("q", "qd"), ("qd", "u"))),
    ("grid 16 (q,qd), hold k*", 16, 1, 125, (("q", "qd"),)),
    ("**grid 16 (q,qd)+(qd,u), hold k\* (identify's)**", 16, 1, 125, (("q", "qd"), ("qd", "u"))),
    ("grid 32 (q,qd)+(qd,u), hold k*", 32, 1, 125, (("q", "qd"), ("qd", "u"))),
    ("grid 16 (q,qd)+(qd,u)+(qd,qdd), hold k*", 16, 1, 125, (("q", "qd"), ("qd", "u"), ("qd", "qdd"))),
)


def bags(data, d):
    """Nominal model, the three bags and the calibrated model in ``d`` (reused when there)."""
    nominal, model = d / "nominal.yaml", d / "mc.yaml"
    if not nominal.exists():
        cli("fit-lwa4p", data, "--runs", "1-80:train", "--out", nominal)
    for name, runs in (("fit", "1-80:train"), ("held", "1-76:heldout"), ("run80", "80"), ("fam5", "81-100")):
        if not (d / name).exists():
            cli("import-lwa4p", data, "--runs", runs, "--out", d / name, "--model", nominal)
    if not model.exists():
        cli("identify", d / "fit", "--calibrate", 5, "--out", model)
    return mdl.load(model), {n: d / n for n in ("fit", "held", "run80", "fam5")}


def read(bag, model):
    series, _ = read_joint_series([bag], list(model.joints), model.plant.dt, (JOINT_STATES, PLANT_INPUT))
    return series


def measure(env, model, held, run80, fam5, viol):
    """Per joint: (a) violating ticks of 81-100 inside; (b) held-out ticks outside (runs 4-76,
    and run 80 on its own); ticks of 81-100 outside."""
    rows = {}
    for n in model.joints:
        out_h, n_h = ev.classify_series(env, n, held[n])
        out_80, n_80 = ev.classify_series(env, n, run80[n])
        out_f, n_f = ev.classify_series(env, n, fam5[n])
        v = viol[n]
        rows[n] = {"viol": int(v.sum()), "viol_inside": int((v & ~out_f).sum()), "held_out": int(out_h.sum()),
                   "held_ticks": n_h, "run80_out": int(out_80.sum()), "run80_ticks": n_80,
                   "fam_out": int(out_f.sum()), "fam_ticks": n_f}
    return rows


def pct(a, b):
    return f"{100 * a / b:.2f} %" if b else "-"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=None, help="the LWA-4P recordings (default: the shipped ones)")
    ap.add_argument("--work", default=None, help="keep (and reuse) the bags and models here")
    ap.add_argument("--verbose", action="store_true", help="print each reachset command on stderr")
    a = ap.parse_args()
    real_data.VERBOSE = a.verbose
    data = str(lwa4p.recordings_dir(a.data))
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(a.work or tmp)
        d.mkdir(parents=True, exist_ok=True)
        model, paths = bags(data, d)
        fit, held, run80, fam5 = (read(paths[k], model) for k in ("fit", "held", "run80", "fam5"))
        thm = model.theorem1()
        viol = {n: check(model.plant, thm, model.estimator, model.checked_xi(n), s.y, s.u, s.segments,
                         model.horizon).violating for n, s in fam5.items()}
        print("| envelope | (a) violating ticks of 81-100 inside: worst joint | all joints | "
              "(b) held-out ticks of 4-76 outside: worst joint | all joints | held-out run 80 outside | "
              "ticks of 81-100 outside |")
        print("|---|---|---|---|---|---|---|")
        rows = [(label, ev.fit(fit, bins=bins, dilation=dil, hold=hold, grids=grids))
                for label, bins, dil, hold, grids in CANDIDATES]
        rows.append(("the model file's (`identify --calibrate 5`)", model.envelope))
        for label, env in rows:
            r = measure(env, model, held, run80, fam5, viol)
            wa = max(r, key=lambda n: r[n]["viol_inside"] / max(r[n]["viol"], 1))
            wb = max(r, key=lambda n: r[n]["held_out"] / max(r[n]["held_ticks"], 1))
            s = {k: sum(x[k] for x in r.values()) for k in next(iter(r.values()))}
            wa_s = f" ({wa})" if r[wa]["viol_inside"] else ""         # the worst joint, when not 0
            wb_s = f" ({wb})" if r[wb]["held_out"] else ""
            print(f"| {label} | {pct(r[wa]['viol_inside'], r[wa]['viol'])}{wa_s} | "
                  f"{s['viol_inside']} of {s['viol']} ({pct(s['viol_inside'], s['viol'])}) | "
                  f"{pct(r[wb]['held_out'], r[wb]['held_ticks'])}{wb_s} | "
                  f"{s['held_out']} of {s['held_ticks']} ({pct(s['held_out'], s['held_ticks'])}) | {pct(s['run80_out'], s['run80_ticks'])} | "
                  f"{pct(s['fam_out'], s['fam_ticks'])} |")
            if real_data.VERBOSE:
                for n, x in r.items():
                    print(f"  {n}: {x}", file=sys.stderr)
        # (b) over every held-out run of 1-80, run 80 (a workspace sweep) included, for the model's envelope
        worst = max(r.values(), key=lambda x: x["held_out"] + x["run80_out"])
        out = sum(x["held_out"] + x["run80_out"] for x in r.values())
        ticks = sum(x["held_ticks"] + x["run80_ticks"] for x in r.values())
        print(f"\n(b) counting held-out run 80, the model file's envelope: worst joint "
              f"{pct(worst['held_out'] + worst['run80_out'], worst['held_ticks'] + worst['run80_ticks'])} "
              f"({worst['held_out'] + worst['run80_out']} of {worst['held_ticks'] + worst['run80_ticks']}), "
              f"all joints {out} of {ticks} ({pct(out, ticks)})")

if __name__ == "__main__":
    main()
