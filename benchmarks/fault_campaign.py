"""Fault campaign (issue 17): every injected fault stops the arm, nothing else does.

The whole simulated system over real DDS (:mod:`reachset_ros.workflows.campaign`), faults
from a seeded schedule (:func:`reachset_ros.sim.campaign.schedule`: every simulator fault
kind on every joint, SIGKILL of the observer, controller and simulator, SIGSTOP of any node
for 50-500 ms, stamp jumps, fault-free stretches; CPU burners on both cores for every other
block of 8 events). Prints the table (docs/reliability.md, "Fault campaign") and writes
``campaign.json`` (every outcome and the score) and the safety evidence sheet
(:mod:`reachset_ros.sim.evidence`: ``evidence.json``, ``evidence.html``; their paths printed)
and the report of its bags against its model (:func:`reachset_ros.report.write_report`:
``report.html``, its path printed) to the work directory.

Run: ``.venv/bin/python benchmarks/fault_campaign.py --events 480 --seed 1 --quiet 4 8`` (about
80 minutes of wall time; six training recordings of 40 s, the inflation one grid step above the
cross-validated one); ``--short`` is the `make test` variant (test/workflows/test_fault_campaign.py): 10 events
after 1-2 s of fault-free running each, no burners, three training recordings of 20 s.
``--realtime-priority 50`` runs the loop's and the stop path's nodes under SCHED_FIFO
(``realtime_priority``, docs/nodes.md; the burners and the recorder stay at the default policy).
``--monitor-lockstep-ticks 0`` lets the simulation run ahead of the monitor's verdicts (the
simulator's ``monitor_lockstep_ticks``, 5 by default; docs/reliability.md, "The monitor trailing
the simulated arm").
Exit status 0 when nothing was missed and no stop was false, 1 otherwise.
"""
import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

from reachset_ros.domain import pick_domain_id
from reachset_ros.workflows.campaign import run_campaign
from reachset_ros.sim import campaign as cp
from reachset_ros.sim import evidence
from reachset_ros.stacks import dump_on_sigusr1


def main(argv=None):
    dump_on_sigusr1()     # kill -USR1: where a run that seems hung is (the test sends it on a timeout)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=320)
    ap.add_argument("--seed", type=int, default=None, help="seed of the schedule (default 1; --short: 92)")
    ap.add_argument("--quiet", type=float, nargs=2, default=(3.0, 8.0), metavar=("MIN", "MAX"),
                    help="fault-free stretch before each event, simulated s (uniform)")
    ap.add_argument("--train", type=float, default=40.0, help="simulated s per training recording")
    ap.add_argument("--train-runs", type=int, default=6, help="training recordings (each a calibration fold)")
    ap.add_argument("--calibrate-margin", type=int, default=2, metavar="N",
                    help="the model's inflation N grid steps above the cross-validated one (identify "
                         "--calibrate-margin; default 2: the run is far longer than a fold, and two 48-min "
                         "runs needed 0.21 where the folds said 0.1 and 0.2; --short: 0)")
    ap.add_argument("--burners", type=float, default=0.5, choices=(0.0, 0.5, 1.0))
    ap.add_argument("--kinds", nargs="+", default=None, help="only these event kinds")
    ap.add_argument("--sim-faults", nargs="+", default=None, help="only these simulator fault kinds")
    ap.add_argument("--model", default=None, help="the monitor's model (skips training and identification)")
    ap.add_argument("--workdir", default=None)
    ap.add_argument("--rescore", default=None, metavar="WORK",
                    help="score an earlier campaign again from its campaign.json and bags (the same --events, "
                         "--seed, --quiet, --burners, --kinds as its run): each stop's effect judged anew")
    ap.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                    help="run the loop's and the stop path's nodes under SCHED_FIFO at N (1-99; needs "
                         "CAP_SYS_NICE; default 0: the default policy, as the burners)")
    ap.add_argument("--monitor-lockstep-ticks", type=int, default=None, metavar="N",
                    help="the simulator's monitor_lockstep_ticks (default: the node's, 5; 0: the simulation "
                         "does not wait for the monitor's verdicts)")
    ap.add_argument("--short", action="store_true", help="the make-test variant: 10 events, no burners")
    a = ap.parse_args(argv)
    if a.short:
        # seed 92: 7 of the 10 events must stop, a link loss and a sparse loss among them
        a.events, a.quiet, a.burners, a.train, a.train_runs = 10, (1.0, 2.0), 0.0, 20.0, 3
        a.calibrate_margin = 0
        a.seed = SHORT_SEED if a.seed is None else a.seed
    a.seed = 1 if a.seed is None else a.seed
    events = cp.schedule(a.seed, a.events, quiet_s=tuple(a.quiet), burner_share=a.burners, kinds=a.kinds,
                         sim_faults=a.sim_faults)
    if a.rescore:
        return rescore(Path(a.rescore), events)
    work = Path(a.workdir or tempfile.mkdtemp(prefix="fault_campaign_")).resolve()
    os.environ["ROS_DOMAIN_ID"] = str(pick_domain_id())
    print(f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} workdir {work}", file=sys.stderr, flush=True)
    outcomes, info = run_campaign(workdir=work, events=events, seed=a.seed, train=a.train, model=a.model,
                                  train_runs=a.train_runs, calibrate_margin=a.calibrate_margin,
                                  realtime_priority=a.realtime_priority,
                                  monitor_lockstep_ticks=a.monitor_lockstep_ticks,
                                  log=lambda s: print(s, file=sys.stderr, flush=True))
    score = cp.score(outcomes, info.get("apparatus_stops", ()))
    (work / "campaign.json").write_text(json.dumps({"info": info, "score": score,
                                                     "outcomes": [o.as_dict() for o in outcomes]}, indent=1))
    code = report(score)
    write_evidence(work, outcomes, info)
    return code


def write_evidence(work, outcomes, info):
    """The safety evidence sheet (:mod:`reachset_ros.sim.evidence`) in the work directory."""
    ev = evidence.evidence(outcomes, info=info, apparatus_stops=info.get("apparatus_stops", ()))
    for path in evidence.write(ev, work):
        print(f"evidence: {path}")
    write_campaign_report(work, outcomes, info)


def write_campaign_report(work, outcomes, info):
    """``report.html``: the campaign's bags checked against its model (``reachset report``); a
    bag the report cannot read is named and the campaign's result stands."""
    from reachset_ros.errors import ReachsetError
    from reachset_ros.report import write_report
    bags = sorted({o.bag for o in outcomes if o.bag and Path(o.bag).exists()})
    if not bags or not info.get("model"):
        return None
    try:
        res = write_report(bags, info["model"], work / "report.html",
                           command=f"reachset report {' '.join(bags)} --model {info['model']} --out {work / 'report.html'}")
    except ReachsetError as e:
        print(f"report: not written ({e})")
        return None
    print(f"report: {res['report']}")
    return res["report"]


#: the short mode's schedule: 10 events, 7 expecting a stop (two accelerations, a bias, a killed
#: observer and simulator, a stamp jump, a link loss), a sparse loss and a quiet stretch that
#: must not stop, a freeze in the tolerance band. (Seed 47 has a killed controller: its stop
#: was once judged not at rest, 0.64 s > 0.5 s with 2.6 mrad of travel, while the restarted
#: controller held the arm; an open item in docs/reliability.md.)
SHORT_SEED = 92


def report(score):
    print(cp.table(score))
    print(json.dumps({k: v for k, v in score.items() if k not in ("misses", "false", "not_at_rest")}, indent=1))
    return 0 if score["missed_stops"] == 0 and score["false_stops"] == 0 else 1


def rescore(work, events):
    """The outcomes of ``work/campaign.json`` with the stops judged again from its bags."""
    from reachset_ros.workflows.campaign import (bag_brakes, bag_stops, frozen_before_motion, judge_stops,
                                                 link_onsets)
    res = json.loads((work / "campaign.json").read_text())
    if [e.label() for e in events] != [o["event"] for o in res["outcomes"]]:
        sys.exit("fault_campaign: error: the schedule of these arguments is not the campaign's (use its --events, "
                 "--seed, --quiet, --burners, --kinds)")
    outcomes = []
    for e, o in zip(events, res["outcomes"]):
        fields = {k: v for k, v in o.items() if k not in ("event", "rest")}
        fields["stops"] = [tuple(x) for x in fields["stops"]]
        fields["quiet_stops"] = [tuple(x) for x in fields["quiet_stops"]]
        outcomes.append(cp.Outcome(e, **{k: v for k, v in fields.items() if k in cp.Outcome.__dataclass_fields__}))
    bag_stops(outcomes)
    judge_stops(outcomes)
    frozen_before_motion(outcomes)
    link_onsets(outcomes)
    bag_brakes(outcomes)
    code = report(cp.score(outcomes, res["info"].get("apparatus_stops", ())))
    write_evidence(work, outcomes, res["info"])
    return code


if __name__ == "__main__":
    sys.exit(main())
