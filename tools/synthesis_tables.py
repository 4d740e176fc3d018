"""The tables of the paper's Sec. IV on the project's simulated arm (docs/synthesis.md).

Subcommands::

    # a bag of the simulated LWA-4P (reachset_ros.sim.simulator, realistic model error) driven by
    # the nodes' control law with the gains of a model file (default: HG 15/30, omega 20, zeta 1)
    .venv/bin/python tools/synthesis_tables.py simulate --seconds 300 --seed 1 [--gains MODEL.yaml] --out BAG

    # everything: bags, `reachset synthesize` runs (two iterations + re-identification, as the
    # paper), the LQG baseline, HG vs ESO; markdown tables on stdout and in DIR/tables.md
    .venv/bin/python tools/synthesis_tables.py tables --dir build/synthesis [--seconds 300]

Every step is a real command line (printed before it runs); outputs that exist are reused,
so a second call only prints the tables. Deterministic for given seeds.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
PY = sys.executable
LQG_R = ("1e-7", "1e-6", "1e-5", "1e-4", "1e-3", "1e-2", "1e-1", "1", "10")
ESO0 = {"observer": "eso", "controller": "compensated", "omega": 20.0, "zeta": 1.0, "l1": 57.1, "l2": 103.3,
        "l3": 18.1, "eps": 0.01}


def simulate(args):
    from reachset_ros.conformance import model as mdl
    from reachset_ros.sim import recordings as sr
    gains = None
    if args.gains:
        m = mdl.load(args.gains)
        gains = {n: j.gains for n, j in m.joints.items() if j.gains}
    elif args.initial == "eso":
        gains = ESO0
    t = time.perf_counter()
    recs = sr.simulate_arm_recordings(args.seconds, gains, seed=args.seed)
    sr.write_recordings(args.out, recs)
    print(f"simulated {args.seconds:g} s ({len(next(iter(recs.values())).y)} ticks, {len(recs)} joints) "
          f"in {time.perf_counter() - t:.1f} s -> {args.out}", file=sys.stderr)


def sh(argv, out_json=None, allow_fail=False):
    """Run a command (printed), return its JSON stdout (cached in ``out_json``).

    With ``allow_fail`` a failure returns ``{"error": stderr}`` (also cached) instead of exiting.
    """
    if out_json is not None and Path(out_json).exists():
        return json.loads(Path(out_json).read_text())
    print("$ " + " ".join(map(str, argv)), file=sys.stderr, flush=True)
    t = time.perf_counter()
    r = subprocess.run(list(map(str, argv)), capture_output=True, text=True, cwd=REPO)
    # `reachset check`/`replay` exit 1 when not conformant: a result (the JSON), not a failure
    verdict = any(str(a) in ("check", "replay") for a in argv[:4]) and r.returncode == 1 and r.stdout.strip()
    if r.returncode != 0 and not verdict:
        if allow_fail:
            res = {"error": r.stderr.strip(), "argv": " ".join(map(str, argv))}
            if out_json is not None:
                Path(out_json).write_text(json.dumps(res))
            print(f"  failed: {res['error']}", file=sys.stderr, flush=True)
            return res
        raise SystemExit(f"failed ({r.returncode}): {r.stderr.strip()}")
    print(f"  ({time.perf_counter() - t:.0f} s)", file=sys.stderr, flush=True)
    if out_json is None:
        return None
    Path(out_json).write_text(r.stdout)
    return json.loads(r.stdout)


def bag(d, name, seconds, seed, gains=None, initial="hg"):
    p = d / name
    if not p.exists():
        argv = [PY, "tools/synthesis_tables.py", "simulate", "--seconds", seconds, "--seed", seed, "--out", p]
        if gains:
            argv += ["--gains", gains]
        elif initial != "hg":
            argv += ["--initial", initial]
        sh(argv)
    return p


# the paper's tables are for the paper's identification: Theorem 1 as eq. 13, without the
# initial-state set that `reachset synthesize` uses by default since issue 16.1
PAPER_ROWS = ("--no-initial-state-set",)


def synth(d, name, bagp, *extra, allow_fail=False):
    out = d / f"{name}.yaml"
    return sh([".venv/bin/reachset", "synthesize", bagp, "--json", "--out", out, *PAPER_ROWS, *extra],
              d / f"{name}.json", allow_fail), out


def tables(args):
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    s = args.seconds
    md = []
    # ---------------- Table II / Fig. 7: combined vs separate, HG + static feedback (omega, zeta)
    # Sec. III-D: synthesise on the data of the current gains, record with the new gains, and
    # re-identify with the controller fixed; if the new data need sets that no longer fit U_p
    # with that controller, synthesise again on them (at most 4 syntheses).
    b0 = bag(d, "hg_iter0", s, 1)
    iters, notes = [], []
    bags = [b0]
    jf = mf = None
    for it in range(1, 5):
        extra = ["--lqg-r", *LQG_R] if it == 2 else []
        j, m = synth(d, f"hg_iter{it}", bags[-1], *extra, "--plot", d / f"plots_hg_iter{it}")
        iters.append((j, m))
        bags.append(bag(d, f"hg_iter{it}_bag", s, 1 + it, gains=m))
        if it >= 2:
            jr, mr = synth(d, f"hg_reid{it}", bags[-1], "--mode", "reidentify", "--model", m,
                           "--plot", d / f"plots_hg_reid{it}", allow_fail=True)
            if "error" not in jr:
                jf, mf = jr, mr
                break
            notes.append(f"re-identification after synthesis {it} infeasible: `{jr['error']}`")
    if jf is None:
        raise SystemExit("no feasible re-identification after 4 syntheses")
    (j1, m1), (j2, m2) = iters[0], iters[1]
    b2 = bags[-1]
    chk = sh([".venv/bin/reachset", "check", b2, "--model", mf, "--json"], d / "hg_final_check.json")
    joints = list(jf["joints"])
    md.append("### Table II: combined synthesis, HG observer (h1 = 15, h2 = 30) + static feedback\n")
    md.append(f"After {len(iters)} syntheses and the re-identification with the controller fixed; "
              "separate approach of synthesis 2 for comparison.\n")
    md.append("| Axis | ‖R_e‖ | ω | ζ | α_W,1 | α_W,2 | α_V | R_u | U_p | ‖R_e‖ separate | ω separate | ζ separate | α_W,1 sep. | α_W,2 sep. | R_u separate |")
    md.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for i, n in enumerate(joints):
        f, sep = jf["joints"][n], j2["joints"][n]["separate"]
        g, gs = f["gains"], sep.get("gains", {})
        if "error" in sep:
            srow = "infeasible | | | | | "
        else:
            srow = (f"{sep['re_norm']:.3f} | {gs['omega']:.2f} | {gs['zeta']:.2f} | {sep['alpha_w'][0]:.4g} | "
                    f"{sep['alpha_w'][1]:.4g} | [{sep['ru'][0]:.1f}, {sep['ru'][1]:.1f}]")
        md.append(f"| {i + 1} | {f['re_norm']:.3f} | {g['omega']:.2f} | {g['zeta']:.2f} | {f['alpha_w'][0]:.4g} | "
                  f"{f['alpha_w'][1]:.4g} | {f['alpha_v'][0]:.3g} | [{f['ru'][0]:.1f}, {f['ru'][1]:.1f}] | "
                  f"±{f['u_max']:g} | {srow} |")
    md.append(f"\nAll final models conformant on the re-identification bag: `reachset check` → "
              f"conformant = {chk['conformant']} "
              f"({sum(j['test_cases'] for j in chk['joints'].values())} test cases).\n")
    def norms(j):
        return ", ".join(f"{j['joints'][n]['re_norm']:.3f}" for n in joints)
    md.append("‖R_e‖ per axis: " + "; ".join(f"synthesis {k + 1}: {norms(j)}" for k, (j, _) in enumerate(iters))
              + f"; re-identified: {norms(jf)}.\n")
    for note in notes:
        md.append(f"- {note}")
    md.append("")
    # ---------------- Table IV: LQG vs ours, axis 1
    n0 = joints[0]
    rows = j2["joints"][n0]["lqg"]
    ours = j2["joints"][n0]
    md.append("### Table IV: LQG (Q = diag(1000, 1000, 0.01, r)) vs our synthesis, axis 1\n")
    md.append("LQG evaluated with the sets of the iteration-2 combined model (as the paper uses its Table II model).\n")
    md.append("| r | ‖R_e‖ | R_u | inside U_p | ‖R_e‖ with sets re-chosen for LQG |")
    md.append("|---|---|---|---|---|")
    for row in rows:
        r = row["r"]
        md.append(f"| {r:g} | {row['re_norm']:.3f} | [{row['ru'][0]:.2f}, {row['ru'][1]:.2f}] | "
                  f"{'yes' if row['ru_inside_up'] else '**no**'} | {row['re_norm_best_sets']:.3f} |")
    md.append(f"| **our method** | **{ours['re_norm']:.3f}** | **[{ours['ru'][0]:.2f}, {ours['ru'][1]:.2f}]** | yes | |\n")
    # ---------------- Table III: HG vs ESO with the controller fixed
    # The paper fixes omega = 20, zeta = 1; on our simulated arm no HG gains then keep R_u
    # inside U_p = +-26 on some axes (the attempt and its message are reported), so the
    # comparison fixes omega = 14, zeta = 1.3 (feasible for every axis) for both observers.
    paper = sh([".venv/bin/reachset", "synthesize", b0, "--json", *PAPER_ROWS, "--free", "h1,h2", "--fix", "omega=20",
                "--fix", "zeta=1"], d / "t3_hg_paper_controller.json", allow_fail=True)
    t3 = ["--fix", "omega=14", "--fix", "zeta=1.3"]
    h1j, h1m = synth(d, "t3_hg_iter1", b0, "--free", "h1,h2", *t3)
    hb = bag(d, "t3_hg_iter1_bag", s, 11, gains=h1m)
    h2j, h2m = synth(d, "t3_hg_iter2", hb, "--free", "h1,h2", *t3, "--plot", d / "plots_t3_hg")
    e0 = bag(d, "eso_iter0", s, 12, initial="eso")
    e1j, e1m = synth(d, "t3_eso_iter1", e0, "--observer", "eso", *t3)
    eb = bag(d, "t3_eso_iter1_bag", s, 13, gains=e1m)
    e2j, e2m = synth(d, "t3_eso_iter2", eb, "--observer", "eso", *t3, "--plot", d / "plots_t3_eso")
    md.append("### Table III: HG vs ESO observers (ω = 14, ζ = 1.3 fixed), two iterations each\n")
    if "error" in paper:
        md.append(f"With the paper's ω = 20, ζ = 1: `{paper['error']}`\n")
    md.append("| Axis | ‖R_e‖ HG | h1 | h2 | α_W,1 | α_W,2 | α_V | ‖R_e‖ ESO | l1 | l2 | l3 | α_W,1 | α_W,2 | α_V |")
    md.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for i, n in enumerate(joints):
        h, e = h2j["joints"][n], e2j["joints"][n]
        md.append(f"| {i + 1} | {h['re_norm']:.3f} | {h['gains']['h1']:.1f} | {h['gains']['h2']:.1f} | "
                  f"{h['alpha_w'][0]:.4g} | {h['alpha_w'][1]:.4g} | {h['alpha_v'][0]:.3g} | "
                  f"{e['re_norm']:.3f} | {e['gains']['l1']:.1f} | {e['gains']['l2']:.1f} | {e['gains']['l3']:.1f} | "
                  f"{e['alpha_w'][0]:.4g} | {e['alpha_w'][1]:.4g} | {e['alpha_v'][0]:.3g} |")
    md.append("")
    timing = {k: v["seconds"] for k, v in (("hg_iter1", j1), ("hg_iter2", j2), ("hg_reidentify", jf),
                                           ("t3_hg_iter2", h2j), ("t3_eso_iter2", e2j))}
    md.append("Wall time of `reachset synthesize` (6 joints, in-process seconds reported by the command): "
              + ", ".join(f"{k} {v:.0f} s" for k, v in timing.items()) + ".\n")
    text = "\n".join(md)
    (d / "tables.md").write_text(text)
    print(text)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("simulate", help="a bag of the simulated arm in closed loop")
    p.add_argument("--seconds", type=float, default=300.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--gains", help="model file whose gains the controller uses")
    p.add_argument("--initial", choices=["hg", "eso"], default="hg", help="initial gains without --gains")
    p.add_argument("--out", required=True)
    p.set_defaults(fn=simulate)
    p = sub.add_parser("tables", help="run everything and print the markdown tables")
    p.add_argument("--dir", default=str(REPO / "build" / "synthesis"))
    p.add_argument("--seconds", type=float, default=300.0)
    p.set_defaults(fn=tables)
    args = ap.parse_args(argv)
    np.seterr(all="ignore")
    args.fn(args)


if __name__ == "__main__":
    main()
