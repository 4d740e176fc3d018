"""The report tests' recordings: the simulator's closed loop written as real bags, a model
identified on one of them by the real command line, and a bag with a fault and a safe stop.

* ``train``: :func:`reachset_ros.sim.recordings.simulate_recordings` (two joints, 12 s),
  written by :func:`~reachset_ros.sim.recordings.write_recordings`;
* ``model.yaml``: ``reachset identify train --horizon 30 --inflation 0.5``;
* ``faulty``: another seed of the same loop with a 0.01 rad sensor bias on ``arm_2_joint`` from
  :data:`FAULT_TICK` on, and a ``/safe_stop`` (active, stamped :data:`STOP_AFTER_TICKS` later,
  as the monitor stamps it with the measurement that triggered it), written by
  :class:`reachset_ros.bags.BagWriter`, with the ``/sim/fault_onset`` header at the fault and the
  stop republished :data:`REPUBLISHED` times as the monitor republishes it.
"""
from pathlib import Path

import numpy as np

from reachset_ros import bags
from reachset_ros.sim import recordings as sr

from cli_helpers import run_cli

JOINTS = ["arm_1_joint", "arm_2_joint"]
TICKS = 3000
FAULT_TICK = 2000
STOP_AFTER_TICKS = 2
BIAS = 0.01
#: messages of the one stop in the bag (the monitor republishes its latched /safe_stop)
REPUBLISHED = 25


def write_faulty(path, recs, stop_stamp):
    """``recs`` with the bias on ``arm_2_joint`` as /joint_states + /plant_input, and one
    active /safe_stop at ``stop_stamp``."""
    SS = bags.typestore().types[bags.SAFE_STOP_TYPE]
    st = recs[JOINTS[0]].stamps
    Y = np.column_stack([recs[n].y for n in JOINTS])
    U = np.column_stack([recs[n].u for n in JOINTS])
    Y[FAULT_TICK:, 1] += BIAS
    with bags.BagWriter(path) as w:
        for k in range(len(st)):
            t = int(st[k])
            w.write(bags.JOINT_STATES, bags.joint_state(t, JOINTS, Y[k]), t + 200_000)
            w.write(bags.PLANT_INPUT, bags.plant_input(t, JOINTS, U[k]), t + 500_000)
            if k == FAULT_TICK:               # the simulator's fault onset: a std_msgs/Header
                w.write(bags.FAULT_ONSET_TOPIC, bags.header(t), t + 100_000, bags.FAULT_ONSET_TYPE)
            if t >= stop_stamp and k < FAULT_TICK + STOP_AFTER_TICKS + REPUBLISHED:
                # the monitor republishes its latched stop, stamped with the triggering measurement
                w.write(bags.SAFE_STOP_TOPIC, SS(
                    header=bags.header(stop_stamp), active=True, reason="arm_2_joint left its reachable set",
                    kind="violation", joint="arm_2_joint", step=2, test_case_start_ns=stop_stamp - 8_000_000,
                    deviation=0.01, bound=0.001, window_bag=""), t + 600_000, bags.SAFE_STOP_TYPE)
    return Path(path)


def make_case(workdir):
    """``{"train", "faulty", "model", "start_ns", "stop_ns"}`` in ``workdir``."""
    d = Path(workdir)
    sr.write_recordings(d / "train", sr.simulate_recordings(JOINTS, TICKS, seed=1))
    recs = sr.simulate_recordings(JOINTS, TICKS, seed=2)
    start = int(recs[JOINTS[0]].stamps[0])
    stop = int(recs[JOINTS[0]].stamps[FAULT_TICK + STOP_AFTER_TICKS])
    write_faulty(d / "faulty", recs, stop)
    p = run_cli("identify", d / "train", "--horizon", 30, "--inflation", 0.5, "--out", d / "model.yaml")
    assert p.returncode == 0, p.stderr
    return {"train": d / "train", "faulty": d / "faulty", "model": d / "model.yaml", "start_ns": start,
            "stop_ns": stop}
