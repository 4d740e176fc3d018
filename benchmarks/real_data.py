"""Real Schunk LWA-4P data on the real-data protocol (docs/real-data.md).

Run: .venv/bin/python benchmarks/real_data.py [--data DIR] [--plots DIR]

Protocol: runs whose number is divisible by 4 (25 runs) are held out; the nominal model, the
sets and the inflation are fitted on the other 75 only. Prints markdown tables:

1. held-out conformance: identify on the 75 training runs with ``--calibrate 5``, check the
   training and the held-out runs at inflation 0 and at the calibrated inflation;
2. leave-one-family-out (extrapolation to an unseen trajectory family): per family, the
   nominal model, the sets and the inflation fitted on the training runs of the other four
   families, checked on every run of the family;
3. the old split (fit on the training runs of 1-70, check 71-100), reported separately.

Every step is a ``reachset`` command (printed with ``--verbose``).
"""
import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
from reachset_ros.robot import lwa4p  # noqa: E402
from reachset_ros.robot.lwa4p import FAMILIES, _runs_spec, is_held_out  # noqa: E402

VERBOSE = False
#: the paper's separate approach, which docs/real-data.md reports: min ||W|| + ||V|| with the fd
#: estimator (identify's defaults have been the detection cost and the lsq estimator since)
PAPER = ("--cost", "linear", "--estimator", "fd")


def cli(*args):
    argv = [sys.executable, "-m", "reachset_ros.cli", *map(str, args)]
    if VERBOSE:
        print("$ reachset " + " ".join(map(str, args)), file=sys.stderr)
    out = subprocess.run(argv, capture_output=True, text=True, cwd=REPO)
    # check/replay exit 1 when not conformant: a result, not a failure
    if out.returncode not in ((0, 1) if args[0] in ("check", "replay") else (0,)):
        raise SystemExit(f"reachset {args[0]} failed ({out.returncode}): {out.stderr.strip()}")
    return json.loads(out.stdout) if "--json" in args else out.stdout


def fitted(data, d, name, fit_runs, check_sets, calibrate=5, plots=None):
    """Nominal model, bags and a calibrated conformance model fitted on ``fit_runs``; the
    check of each of ``check_sets`` ({label: runs}) at inflation 0 and calibrated."""
    fit = _runs_spec(fit_runs)
    nominal = d / f"{name}_nominal.yaml"
    cli("fit-lwa4p", data, "--runs", fit, "--out", nominal)
    cli("import-lwa4p", data, "--runs", fit, "--out", d / f"{name}_fit", "--model", nominal)
    m0, mc = d / f"{name}_m0.yaml", d / f"{name}_mc.yaml"
    ident = cli("identify", d / f"{name}_fit", *PAPER, "--calibrate", calibrate, "--out", mc, "--json")
    cli("identify", d / f"{name}_fit", *PAPER, "--out", m0)
    res = {"ident": ident, "checks": {}}
    for label, runs in check_sets.items():
        bag = d / f"{name}_{label}"
        if runs == fit_runs:
            bag = d / f"{name}_fit"
        else:
            cli("import-lwa4p", data, "--runs", _runs_spec(runs), "--out", bag, "--model", nominal)
        extra = []
        if plots and label in plots:
            extra = ["--plot", plots[label]]
        res["checks"][label] = (cli("check", bag, "--model", m0, "--json"),
                                cli("check", bag, "--model", mc, "--json", *extra))
    return res


def share(chk, joint):
    ticks = chk["data"]["messages"]["/plant_input"]
    v = chk["joints"][joint]["violations"]
    return f"{v} ({100 * v / ticks:.2f} %)"


def main():
    global VERBOSE
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=None, help="the LWA-4P recordings (default: the shipped reachset_ros/data/lwa4p_iros2018)")
    ap.add_argument("--plots", default=None, help="write the deviation plots of the protocol run here")
    ap.add_argument("--verbose", action="store_true", help="print each reachset command on stderr")
    a = ap.parse_args()
    a.data = str(lwa4p.recordings_dir(a.data))
    VERBOSE = a.verbose
    train = [r for r in range(1, 101) if not is_held_out(r)]
    held = [r for r in range(1, 101) if is_held_out(r)]
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        plots = None
        if a.plots:
            plots = {"train": str(Path(a.plots) / "train"), "heldout": str(Path(a.plots) / "heldout")}
        main_run = fitted(a.data, d, "protocol", train, {"train": train, "heldout": held}, plots=plots)
        ident = main_run["ident"]
        print(f"## Protocol: fit on the 75 training runs, check the 25 held-out runs (k* = {ident['horizon']}, "
              f"`--calibrate 5`, model inflation {ident['inflation']})\n")
        print("| joint | alpha_W | alpha_V | inflation (CV) | test cases train | violating ticks train, "
              "inflation 0 | test cases held out | violating ticks held out, inflation 0 | "
              f"violating ticks held out, inflation {ident['inflation']} |")
        print("|---|---|---|---|---|---|---|---|---|")
        tr0, _ = main_run["checks"]["train"]
        h0, hc = main_run["checks"]["heldout"]
        for j, v in ident["joints"].items():
            cv = v["calibration"]["inflation"]      # the joint's own cross-validated value (v["inflation"]: applied)
            print(f"| {j} | {[round(x, 4) for x in v['alpha_w']]} | {v['alpha_v'][0]:.3g} | {cv} | "
                  f"{tr0['joints'][j]['test_cases']} | {share(tr0, j)} | {h0['joints'][j]['test_cases']} | "
                  f"{share(h0, j)} | {share(hc, j)} |")
        print("\n## Leave one family out (extrapolation to an unseen trajectory family)\n")
        print("Per family: nominal model, sets and inflation (`--calibrate 5`) fitted on the training runs of "
              "the other four families; checked on all 20 runs of the family. Violating ticks (share) per "
              "joint at inflation 0 / at the calibrated inflation.\n")
        joints = list(ident["joints"])
        print("| family | inflation | " + " | ".join(joints) + " |")
        print("|---|---|" + "---|" * len(joints))
        for lo, hi in FAMILIES:
            fam = list(range(lo, hi + 1))
            fit_runs = [r for r in train if r not in fam]
            res = fitted(a.data, d, f"lofo{lo}", fit_runs, {"family": fam})
            c0, cc = res["checks"]["family"]
            print(f"| {lo}-{hi} | {res['ident']['inflation']} | "
                  + " | ".join(f"{share(c0, j)} / {share(cc, j)}" for j in joints) + " |")
        print("\n## The old split: fit on the training runs of 1-70, check 71-100\n")
        fit_runs = [r for r in train if r <= 70]
        res = fitted(a.data, d, "old", fit_runs, {"v": list(range(71, 101))})
        c0, cc = res["checks"]["v"]
        print(f"Model inflation {res['ident']['inflation']}. Violating ticks (share) on 71-100 at inflation 0 / "
              "calibrated:\n")
        print("| " + " | ".join(joints) + " |")
        print("|" + "---|" * len(joints))
        print("| " + " | ".join(f"{share(c0, j)} / {share(cc, j)}" for j in joints) + " |")


if __name__ == "__main__":
    main()
