"""``reachset replay``: the bag through the online monitor's tick-by-tick code path."""
import time

import numpy as np

from .. import conformance as cf
from .. import model as mdl
from ..monitor import JointMonitor, MonitorModel
from . import emit
from ._bagargs import add_bag_arguments, load_series

NAME = "replay"
HELP = "replay bags through the online monitor core tick by tick (same verdicts as check)"


def add_arguments(p):
    add_bag_arguments(p)
    p.add_argument("--model", required=True, help="model YAML (identify/synthesize output)")


def replay_series(model, name, s, thm=None):
    mon = JointMonitor(MonitorModel.from_model(model, name, thm))
    violations, first, checks = 0, None, 0
    durations = np.empty(len(s.stamps))
    for i in range(len(s.stamps)):
        t0 = time.perf_counter()
        r = mon.tick(int(s.stamps[i]), s.y[i], s.u[i])
        durations[i] = time.perf_counter() - t0
        checks += r.checked
        if r.status == "violation":
            violations += 1
            if first is None:
                first = int(s.stamps[i])
    starts = cf.test_case_starts(s.segments, model.estimator.history)[0]
    return {"violations": violations, "first_violation_ns": first, "test_cases": int(len(starts)),
            "checks": checks}, durations


def run(args):
    model = mdl.load(args.model)
    series, report = load_series(args.bags, args.joints, model.plant.dt, restrict=list(model.joints))
    thm = cf.Theorem1.build(model.plant, model.horizon)
    joints, durs, ticks = {}, [], 0
    for name, s in series.items():
        if name not in model.joints:
            from ..errors import ReachsetError
            raise ReachsetError(f"joint {name} is not in the model {args.model}")
        joints[name], d = replay_series(model, name, s, thm)
        durs.append(d)
        ticks = max(ticks, len(s.stamps))
    d = np.concatenate(durs) * 1e6 if durs else np.zeros(1)
    result = {"conformant": all(j["violations"] == 0 for j in joints.values()), "joints": joints,
              "ticks": ticks, "timing_us_per_joint_tick": {"mean": float(d.mean()), "p99": float(np.percentile(d, 99)),
                                                           "max": float(d.max())},
              "data": report.as_dict()}
    emit(args, result, ("conformant" if result["conformant"] else "NOT conformant") + "\n" + "\n".join(
        f"{n}: {j['violations']} violating ticks" for n, j in joints.items())
        + f"\n{ticks} ticks, {d.mean():.0f} us mean per joint and tick")
