"""``reachset inspect``: what a bag holds, and whether ``reachset identify`` can use it.

For every topic: type, message count, rate from the log times; for JointState and
PlantInput topics also from the header stamps: the sampling period (median stamp step) and
its jitter, the joint names, and which of position/velocity/effort are filled. Then the
``identify`` command that works on the bags, or why none can (issue 15, item 1).

Bags from the wild (issue 36.5): a topic whose messages are not valid CDR for its type is named
(``malformed`` in its row, ``malformed_topics``) and the rest is read; periods, rates and jitter
are taken within each bag (the gap between two bags is not jitter); active safe stops and
simulated fault onsets are warned about (``warnings``) before an identify command is printed.
"""
import shlex
from pathlib import Path

import numpy as np

from ..bags import (FAULT_ONSET_TOPIC, FAULT_ONSET_TYPE, JOINT_STATE_TYPE, JOINT_STATES, PLANT_INPUT, PLANT_INPUT_TYPE,
                    SAFE_STOP_TYPE, check_bag, header_stamp_ns, typestore)
from ..errors import ReachsetError, first_line
from . import emit, help_of

NAME = "inspect"
HELP = help_of(NAME)

#: the kind of the monitor's start-up stop (held until its model is loaded): not warned about
NOT_READY = "not_ready"
#: the arrays of each type whose filling is reported
FIELDS = {JOINT_STATE_TYPE: ("position", "velocity", "effort"), PLANT_INPUT_TYPE: ("acceleration",)}


def add_arguments(p):
    p.add_argument("bags", nargs="+", help="rosbag2 directories, or bare .mcap / .db3 files")
    p.add_argument("--robot", metavar="URDF",
                   help="the robot's URDF: the suggested command computes u_p from the effort with it when "
                        "the bag has no plant-input topic (--input effort)")
    p.add_argument("--nominal", metavar="PARAMS.yaml", help="with --robot: identified parameters over the URDF")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _times(groups):
    """Rate, median step, jitter of the times (ns) of each bag: steps are taken within a bag
    only, so the gap between two bags given together is neither a step nor jitter."""
    runs = [np.sort(np.asarray(g, dtype=np.int64)) for g in groups if len(g)]
    steps = [np.diff(t) for t in runs if len(t) > 1]
    if not steps:
        return {"rate_hz": 0.0, "period_ms": None, "jitter_ms": None}
    d = np.concatenate(steps) * 1e-6
    med = float(np.median(d))
    span = sum(int(t[-1] - t[0]) for t in runs)
    return {"rate_hz": float(len(d) / (span * 1e-9)) if span > 0 else 0.0,
            "period_ms": med, "jitter_ms": {"std": float(np.std(d)), "max_abs_dev": float(np.max(np.abs(d - med)))}}


def _decoded(topic, msgtype):
    """Whether inspect decodes the messages of a topic: FIELDS types, and the safe stops and
    simulated fault onsets it warns about."""
    return msgtype in FIELDS or msgtype == SAFE_STOP_TYPE or (topic, msgtype) == (FAULT_ONSET_TOPIC,
                                                                                   FAULT_ONSET_TYPE)


def _decode(ts, raw, msgtype):
    """``(message, None)``, or ``(None, why)`` for a payload that is not valid CDR of its type."""
    try:
        return ts.deserialize_cdr(raw, msgtype), None
    except Exception as ex:  # noqa: BLE001 (rosbags raises SerdeError, struct.error, IndexError, ...)
        return None, f"{type(ex).__name__}: {first_line(ex)}"


def _entry(topics, c, path):
    e = topics.setdefault(c.topic, {"type": c.msgtype, "count": 0, "log": [], "stamps": [], "names": [],
                                    "filled": {}, "full": {}, "bad": 0, "why": None})
    if e["type"] != c.msgtype:
        raise ReachsetError(f"{path}: topic {c.topic} has type {c.msgtype} here, {e['type']} before")
    e["log"].append([])
    e["stamps"].append([])
    return e


def _add(e, msg, *, msgtype, topic, t, events):
    """Count one decoded message: its stamp, names, filled arrays, or the event it reports."""
    if msgtype == SAFE_STOP_TYPE:
        if msg.active and msg.kind != NOT_READY:   # the monitor's start-up hold is no fault
            events["stops"].append(f"{topic} at log time {t} ns ({msg.kind}: {msg.reason})")
        return
    if topic == FAULT_ONSET_TOPIC and msgtype == FAULT_ONSET_TYPE:
        events["faults"].append(f"{topic} at log time {t} ns")
        return
    e["stamps"][-1].append(header_stamp_ns(msg))
    names = list(msg.name)
    if names not in e["names"] and len(e["names"]) < 8:
        e["names"].append(names)
    for f in FIELDS[msgtype]:
        n = len(getattr(msg, f))
        full = n > 0 and (n == len(names) or not names)
        e["filled"][f] = e["filled"].get(f, True) and full
        e["full"][f] = e["full"].get(f, 0) + full


def _read_bag(path, ts, topics, events):
    from rosbags.rosbag2 import Reader  # lazy: rosbags.rosbag2's start-up (issue 38.1)
    with Reader(path) as reader:
        entries = {c.topic: _entry(topics, c, path) for c in reader.connections}
        for conn, t, raw in reader.messages():
            e = entries[conn.topic]
            e["count"] += 1
            e["log"][-1].append(t)
            if not _decoded(conn.topic, conn.msgtype):
                continue
            msg, why = _decode(ts, raw, conn.msgtype)
            if msg is None:       # a malformed topic is named, and the rest of the bag is read
                e["bad"] += 1
                e["why"] = e["why"] or f"{why} (first at log time {t} ns in {path})"
                continue
            _add(e, msg, msgtype=conn.msgtype, topic=conn.topic, t=t, events=events)


def inspect_bags(paths, events=None):
    """The per-topic report of the bags (merged over the bags by topic).

    A topic whose messages are not valid CDR for its type gets ``malformed`` (messages, and
    why the first one is not) and the other topics are read on; ``events`` (a dict, filled when
    given): ``stops`` (active safe stops) and ``faults`` (simulated fault onsets) as lines.
    """
    ts = typestore()
    topics = {}
    events = {"stops": [], "faults": []} if events is None else events
    events.setdefault("stops", [])
    events.setdefault("faults", [])
    for p in paths:
        path = Path(p)
        check_bag(path)   # metadata, missing or truncated storage named as every reader names them
        try:
            _read_bag(path, ts, topics, events)
        except ReachsetError:
            raise
        except Exception as ex:  # rosbags raises many types for damaged or unsupported bags
            first = str(ex).splitlines()[0] if str(ex) else ""
            raise ReachsetError(f"{path}: unreadable bag ({type(ex).__name__}" + (f": {first})" if first else ")"))
    out = {}
    for topic, e in sorted(topics.items()):
        row = {"type": e["type"], "count": e["count"], "log_time": _times(e["log"])}
        if e["type"] in FIELDS:
            row["stamps"] = _times(e["stamps"])
            row["joint_names"] = e["names"]
            row["filled"] = e["filled"]
            good = e["count"] - e["bad"]
            row["filled_share"] = {f: v / good for f, v in e["full"].items()} if good else {}
        if e["bad"]:
            row["malformed"] = {"messages": e["bad"], "reason": e["why"]}
        out[topic] = row
    return out


#: share of JointState messages with position, velocity and effort all filled from which
#: ``--input effort`` is suggested (runs end with a sample without effort, as the LWA-4P's do)
EFFORT_SHARE = 0.9


def identify_command(paths, topics, robot=None, nominal=None):
    """(command or None, reason): the ``reachset identify`` that works on these bags.

    Without a plant-input topic, the command uses ``--input effort`` when the measurement
    topic carries position, velocity and effort and ``robot`` (a URDF) is given. Malformed
    topics (``malformed`` in their row) are not candidates: identify could not read them."""
    js = [t for t, r in topics.items() if r["type"] == JOINT_STATE_TYPE and "malformed" not in r]
    pi = [t for t, r in topics.items() if r["type"] == PLANT_INPUT_TYPE and "malformed" not in r]
    if not js:
        bad = [t for t, r in topics.items() if r["type"] == JOINT_STATE_TYPE]
        return None, "no sensor_msgs/msg/JointState topic" + (f" that is not malformed ({', '.join(bad)})"
                                                              if bad else "")
    y_topic = JOINT_STATES if JOINT_STATES in js else js[0]
    if len(js) > 1 and JOINT_STATES not in js:
        return None, (f"several JointState topics ({', '.join(js)}): choose the measurement with "
                      "--joint-states-topic")
    r = topics[y_topic]
    effort = None
    if not pi:
        share = r.get("filled_share", {})
        has_effort = all(share.get(f, 0.0) >= EFFORT_SHARE for f in ("position", "velocity", "effort"))
        why = "no reachset_msgs/msg/PlantInput topic"
        if not has_effort:
            return None, why + f"; {y_topic} lacks velocity or effort, so u_p cannot be computed either"
        if robot is None:
            return None, (why + f"; {y_topic} has position, velocity and effort: pass the robot's URDF "
                          "(reachset inspect BAG --robot URDF) for the command with --input effort")
        from ..robot.effort import load_effort_input      # Pinocchio: only when asked for
        effort = load_effort_input(robot, nominal)
    else:
        u_topic = PLANT_INPUT if PLANT_INPUT in pi else pi[0]
        if len(pi) > 1 and PLANT_INPUT not in pi:
            return None, f"several PlantInput topics ({', '.join(pi)}): choose one with --input-topic"
    names = r["joint_names"]
    unnamed = ""
    if not names or any(not n for n in names):
        if effort is None:
            return None, (f"{y_topic} messages without joint names: pass --joint-names with the names of "
                          "their arrays, in order")
        joints = list(effort.joint_names)
        unnamed = f" --joint-names {','.join(joints)}"
    elif len(names) > 1:
        joints = sorted(set.intersection(*(set(n) for n in names)))
    else:
        joints = list(names[0])
    lock = ""
    if effort is not None:
        missing = [j for j in effort.joint_names if j not in joints]
        if missing:
            if len(missing) == len(effort.joint_names):
                return None, f"no joint of {robot} is on {y_topic}"
            effort = load_effort_input(robot, nominal, lock=missing)
            lock = f" --lock-joints {','.join(missing)}"
        joints = list(effort.joint_names)
    period = r["stamps"]["period_ms"]
    if not period:
        return None, f"fewer than two {JOINT_STATES} messages"
    dt = round(period * 1e-3, 6)
    cmd = "reachset identify " + " ".join(shlex.quote(str(p)) for p in paths) + f" --joints {','.join(joints)} --dt {dt:g}"
    if y_topic != JOINT_STATES:
        cmd += f" --joint-states-topic {y_topic}"
    if effort is not None:
        cmd += f" --input effort --robot {shlex.quote(effort.urdf)}" + (
            f" --nominal {shlex.quote(effort.nominal)}" if effort.nominal else "")
    elif u_topic != PLANT_INPUT:
        cmd += f" --input-topic {u_topic}"
    cmd += lock + unnamed
    why = f"sampling period {period:.4g} ms measured from the {y_topic} stamps"
    if lock:
        why += (f"; joints of the URDF the bag does not carry are locked at their neutral configuration "
                f"({lock.split()[-1]}): right for a gripper's fingers, wrong for an arm joint")
    return cmd, why


def hazards(events):
    """One warning line per kind of event that makes a bag unfit for identification as it is:
    active safe stops and simulated fault onsets (identify fits the nominal model and its
    sets to all the data it is given, faults and braking included)."""
    out = []
    for key, what in (("stops", "active safe stop"), ("faults", "fault onset")):
        ev = events.get(key, [])
        if ev:
            out.append(f"{len(ev)} {what}{'s' if len(ev) > 1 else ''} (first: {ev[0]}): the bag holds a "
                       "stopped or faulty run; identify only on fault-free data (cut the bag, or choose "
                       "other bags)")
    return out


def _topic_line(t, r):
    lt = r["log_time"]
    line = f"{t} [{r['type']}]: {r['count']} messages, {lt['rate_hz']:.4g} Hz (log time)"
    if "stamps" in r and r["stamps"]["period_ms"] is not None:
        s = r["stamps"]
        line += (f"; stamp period {s['period_ms']:.4g} ms (jitter std {s['jitter_ms']['std']:.3g} ms, "
                 f"max {s['jitter_ms']['max_abs_dev']:.3g} ms); joints {r['joint_names'][0] if r['joint_names'] else []}"
                 f"; filled: {', '.join(k for k, v in r['filled'].items() if v) or 'none'}")
    if "malformed" in r:
        m = r["malformed"]
        line += f"; MALFORMED: {m['messages']} of {r['count']} messages are not valid CDR for the type"
    return line


def run(args):
    if args.nominal is not None and args.robot is None:
        raise ReachsetError("--nominal needs --robot URDF")
    events = {}
    topics = inspect_bags(args.bags, events)
    cmd, why = identify_command(args.bags, topics, args.robot, args.nominal)
    warnings = hazards(events)
    malformed = {t: r["malformed"]["reason"] for t, r in topics.items() if "malformed" in r}
    result = {"bags": [str(p) for p in args.bags], "topics": topics, "malformed_topics": malformed,
              "warnings": warnings, "identify": {"command": cmd, "reason": why, "warnings": warnings}}
    lines = [_topic_line(t, r) for t, r in topics.items()]
    lines += [f"malformed topic {t} (skipped): {why_}" for t, why_ in malformed.items()]
    lines += [f"WARNING: {w}" for w in warnings]
    if cmd:
        lines.append(("identify (read the WARNING first): " if warnings else "identify: ") + cmd)
    else:
        lines.append("no identify command works: " + why)
    emit(args, result, "\n".join(lines))
