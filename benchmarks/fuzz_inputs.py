"""Fuzz the bag reader and the model-file loader (hypothesis): every failure must be clean.

Syntax::

    .venv/bin/python benchmarks/fuzz_inputs.py [--seconds 120] [--seed 0] [--out build/fuzz]
                                               [--targets mcap,zstd,sqlite3,metadata,model]

Targets, each starting from a small valid input and mutated by hypothesis:

- ``mcap``, ``zstd``, ``sqlite3``: the storage file of a small two-joint bag (plain MCAP as
  :class:`reachset_ros.bags.BagWriter` writes it, MCAP with zstd-compressed chunks, sqlite3)
  with random byte flips, overwritten and inserted runs, deletions and truncations, read
  with :func:`reachset_ros.bags.read_joint_series` (the function every command uses);
- ``metadata``: the bag's ``metadata.yaml``, as bytes (same mutations) and as YAML (values
  replaced by random YAML values, keys deleted), then read the same way;
- ``model``: model files as ``reachset identify`` writes them (the LWA-4P joint plant by
  name, and one with explicit plant matrices), as bytes and as YAML, loaded with
  :func:`reachset_ros.conformance.model.load`.

A case passes if it returns or raises :class:`~reachset_ros.errors.ReachsetError`. Anything
else is a crash: its traceback is printed and its input saved under ``--out``. A loaded
model or read bag is also checked for what the commands rely on (finite, non-negative
sets and a positive sampling time; stamps increasing and values finite inside segments);
a violation counts as a crash too. A case that takes more than ``--case-timeout`` seconds
is stopped and counted as a hang. The address space is limited (``--memory-mb``) so that a
runaway allocation is a ``MemoryError``, not an exhausted machine.

Prints the number of cases per target and the duration; the exit status is 1 if any
crash or hang was found. Results of a run: docs/reliability.md, "Fuzzing".
"""
import argparse
import math
import os
import re
import resource
import shutil
import signal
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

import numpy as np
import yaml
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import seed as hseed
from hypothesis import strategies as st

from reachset_ros import bags
from reachset_ros.conformance import model as mdl
from reachset_ros.errors import ReachsetError
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.systems.plant import lwa4p_joint_plant

T0 = 1_700_000_000_000_000_000
DT_NS = 4_000_000
TARGETS = ("mcap", "zstd", "sqlite3", "metadata", "model")


class Hang(Exception):
    """A case ran longer than --case-timeout."""


# ------------------------------------------------------------------ seed inputs
def _messages(n=60):
    rng = np.random.default_rng(0)
    names = ["arm_1_joint", "arm_2_joint"]
    for i in range(n):
        t = T0 + DT_NS * i
        yield t, bags.JOINT_STATES, bags.joint_state(t, names, rng.normal(size=2), rng.normal(size=2))
        yield t + 1000, bags.PLANT_INPUT, bags.plant_input(t, names[::-1] if i % 2 else names,
                                                            rng.normal(size=2))


def make_seed_bags(root):
    """{target: bag directory} of small valid bags."""
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
    out = {}
    with bags.BagWriter(root / "mcap") as w:
        for t, topic, msg in _messages():
            w.write(topic, msg, t)
    out["mcap"] = out["metadata"] = root / "mcap"
    for name, plugin, compress in (("zstd", StoragePlugin.MCAP, True), ("sqlite3", StoragePlugin.SQLITE3, False)):
        w = Writer(root / name, version=9, storage_plugin=plugin)
        if compress:
            w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        conns = {}
        with w:
            for t, topic, msg in _messages():
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, msg.__msgtype__, typestore=bags.typestore())
                w.write(conns[topic], t, bags.typestore().serialize_cdr(msg, msg.__msgtype__))
        out[name] = root / name
    for name in ("mcap", "zstd", "sqlite3"):
        bags.read_joint_series([out[name]])            # the seeds themselves read cleanly
    return out


def make_seed_models(root):
    """Two valid model files: the LWA-4P joint plant by name, and explicit plant matrices."""
    p = lwa4p_joint_plant()
    joints = {n: mdl.JointSets((0.05, 1.5), (3e-4,), (0.0,) * 5, (0.0,), 500, 125,
                               {"observer": "hg", "omega": 10.0, "zeta": 0.8, "h1": 15.0, "h2": 30.0})
              for n in ("arm_1_joint", "arm_2_joint")}
    specs = {"lwa4p": {"kind": "lwa4p_joint", "dt": 0.004},
             "matrices": {"kind": "matrices", "dt": 0.004,
                          **{k: getattr(p, k).tolist() for k in ("A", "B", "C", "Gw", "Gv")}}}
    out = []
    for name, spec in specs.items():
        m = mdl.ConformanceModel(mdl.plant_from_spec(spec), spec, Estimator("fd"), 125, joints, 0.05, {"bags": []})
        mdl.save(m, root / f"{name}.yaml")
        mdl.load(root / f"{name}.yaml")
        out.append(root / f"{name}.yaml")
    return out


# ------------------------------------------------------------------ mutations
def byte_ops(size):
    pos = st.integers(0, max(size - 1, 0))
    return st.one_of(
        st.tuples(st.just("flip"), pos, st.integers(0, 7)),
        st.tuples(st.just("set"), pos, st.sampled_from([0x00, 0xFF, 0x7F, 0x80, 0x01, 0x05, 0x06])),
        st.tuples(st.just("overwrite"), pos, st.binary(min_size=1, max_size=16)),
        st.tuples(st.just("insert"), pos, st.binary(min_size=1, max_size=16)),
        st.tuples(st.just("delete"), pos, st.integers(1, 64)),
        st.tuples(st.just("truncate"), pos),
        st.tuples(st.just("u32"), pos, st.sampled_from([0, 1, 2**31 - 1, 2**32 - 1, 2**16, 7])),
        st.tuples(st.just("u64"), pos, st.sampled_from([0, 1, 2**63 - 1, 2**64 - 1, 2**40])),
    )


def mutate_bytes(data, ops):
    b = bytearray(data)
    for op in ops:
        kind, at = op[0], min(op[1], max(len(b) - 1, 0))
        if kind == "flip" and b:
            b[at] ^= 1 << op[2]
        elif kind == "set" and b:
            b[at] = op[2]
        elif kind == "overwrite":
            b[at:at + len(op[2])] = op[2]
        elif kind == "insert":
            b[at:at] = op[2]
        elif kind == "delete":
            del b[at:at + op[2]]
        elif kind == "truncate":
            del b[at:]
        elif kind in ("u32", "u64"):
            n = 4 if kind == "u32" else 8
            b[at:at + n] = int(op[2]).to_bytes(n, "little")
    return bytes(b)


def yaml_values():
    scalars = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70),
                        st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
                        st.sampled_from(["", "mcap", "sqlite3", "zstd", "lwa4p_joint", "matrices", "fd",
                                         "reachset_ros/model/1", "-1", "1e400", ".nan"]))
    return st.recursive(scalars, lambda c: st.one_of(st.lists(c, max_size=4),
                                                     st.dictionaries(st.text(max_size=8), c, max_size=3)),
                        max_leaves=10)


def _paths(doc, prefix=()):
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, prefix + (i,))


def yaml_ops(doc):
    paths = list(_paths(doc))
    return st.lists(st.tuples(st.sampled_from(paths), st.sampled_from(["replace", "delete"]), yaml_values()),
                    min_size=1, max_size=4)


def mutate_yaml(doc, ops):
    import copy
    d = copy.deepcopy(doc)
    for path, kind, value in ops:
        if not path:
            d = value
            continue
        node = d
        try:
            for k in path[:-1]:
                node = node[k]
            if kind == "delete":
                del node[path[-1]]
            else:
                node[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            pass                        # the path no longer exists after an earlier op
    return yaml.safe_dump(d, allow_unicode=True).encode()


# ------------------------------------------------------------------ invariants of accepted inputs
def check_series(series):
    for name, s in series.items():
        for a, b in s.segments:
            st_ = np.asarray(s.stamps[a:b])
            if b - a > 1 and not np.all(np.diff(st_) > 0):
                raise AssertionError(f"joint {name}: stamps not increasing in segment {(a, b)}")
            if not (np.all(np.isfinite(s.y[a:b])) and np.all(np.isfinite(s.u[a:b]))):
                raise AssertionError(f"joint {name}: non-finite value in segment {(a, b)}")


def check_model(m):
    p = m.plant
    if not (math.isfinite(p.dt) and p.dt > 0):
        raise AssertionError(f"accepted model with dt {p.dt}")
    for k in ("A", "B", "C", "Gw", "Gv"):
        if not np.all(np.isfinite(getattr(p, k))):
            raise AssertionError(f"accepted model with non-finite plant {k}")
    if not (isinstance(m.horizon, int) and m.horizon >= 0):
        raise AssertionError(f"accepted model with horizon {m.horizon!r}")
    if not (math.isfinite(m.inflation) and m.inflation >= 0):
        raise AssertionError(f"accepted model with inflation {m.inflation}")
    for n, j in m.joints.items():
        vals = np.array(j.alpha_w + j.alpha_v + j.c_w + j.c_v, float)
        if not np.all(np.isfinite(vals)) or min(j.alpha_w + j.alpha_v) < 0:
            raise AssertionError(f"accepted model with bad sets for joint {n}")
        if not isinstance(j.gains, dict):
            raise AssertionError(f"accepted model with gains {j.gains!r}")


# ------------------------------------------------------------------ the fuzzer
#: Exception types that mean a bug when raised by the package's own code, even when the bag
#: reader's catch-all (it wraps whatever rosbags raises for a damaged file) turned them into
#: a clean ReachsetError. (The model loader converts such errors on purpose, field by field.)
BUG_TYPES = (IndexError, KeyError, TypeError, AttributeError, NameError, AssertionError, ZeroDivisionError,
             UnboundLocalError)
PKG = str(Path(bags.__file__).resolve().parent) + os.sep


def _ours(filename):
    return str(Path(filename).resolve()).startswith(PKG)


def masked_bug(err):
    """The exception behind a ReachsetError if it is a BUG_TYPES raised in reachset_ros code."""
    seen, e = set(), err.__cause__ or err.__context__
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, BUG_TYPES) and e.__traceback__ is not None:
            inner = traceback.extract_tb(e.__traceback__)[-1]
            if _ours(inner.filename):
                return e
        e = e.__cause__ or e.__context__
    return None


class Fuzzer:
    def __init__(self, work, out, case_timeout):
        self.work, self.out, self.case_timeout = work, out, case_timeout
        self.cases, self.clean, self.accepted, self.crash_cases = Counter(), Counter(), Counter(), Counter()
        self.crashes = {}           # signature -> (target, saved input, traceback)
        self.messages = {t: Counter() for t in TARGETS}     # clean error lines, digits as N

    def run_case(self, target, fn, save):
        """Run one case; ReachsetError is clean, anything else is recorded as a crash."""
        self.cases[target] += 1
        signal.setitimer(signal.ITIMER_REAL, self.case_timeout)
        try:
            fn()
            self.accepted[target] += 1
        except ReachsetError as e:
            bug = masked_bug(e) if target != "model" else None
            if bug is not None:
                self._record(target, bug, save, "masked ")
                return
            self.clean[target] += 1
            msg = re.sub(r"\d+", "N", str(e).replace(str(self.work), "WORK"))
            self.messages[target][msg[:90]] += 1
        except BaseException as e:  # noqa: BLE001 (that is the point)
            signal.setitimer(signal.ITIMER_REAL, 0)
            if isinstance(e, KeyboardInterrupt):
                raise
            self._record(target, e, save)
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)

    def _record(self, target, e, save, how=""):
        self.crash_cases[target] += 1
        tb = traceback.extract_tb(e.__traceback__)
        where = next((f"{Path(f.filename).name}:{f.lineno}" for f in reversed(tb) if _ours(f.filename)),
                     f"{Path(tb[-1].filename).name}:{tb[-1].lineno}")
        sig = (target, how + type(e).__name__, where)
        if sig not in self.crashes:
            dest = save(self.out / f"{target}-{len(self.crashes)}")
            text = "".join(traceback.format_exception(e))
            (dest.with_suffix(".txt")).write_text(text)
            self.crashes[sig] = (target, dest, text)
            print(f"CRASH {target}: {how}{type(e).__name__} at {where}: {str(e).splitlines()[0] if str(e) else ''}"
                  f"\n  input saved to {dest}", flush=True)

    # one hypothesis test per target; each call runs a batch of examples
    def bag_batch(self, target, seed_dir, batch, seed):
        which = "metadata" if target == "metadata" else "storage"
        bag = self.work / target
        if bag.exists():
            shutil.rmtree(bag)
        shutil.copytree(seed_dir, bag)
        storage = next(p for p in bag.iterdir() if p.name != "metadata.yaml")
        orig = {p.name: p.read_bytes() for p in bag.iterdir()}
        victim = bag / "metadata.yaml" if which == "metadata" else storage
        meta_doc = yaml.safe_load(orig["metadata.yaml"])
        strategy = st.one_of(st.tuples(st.just("bytes"), st.lists(byte_ops(len(orig[victim.name])), min_size=1,
                                                                    max_size=6)))
        if which == "metadata":
            strategy = st.one_of(strategy, st.tuples(st.just("yaml"), yaml_ops(meta_doc)))

        def case(kind, ops):
            if kind == "bytes":
                data = mutate_bytes(orig[victim.name], ops)
            else:
                data = mutate_yaml(meta_doc, ops)
            for name, content in orig.items():
                (bag / name).write_bytes(content)
            victim.write_bytes(data)

            def read():
                series, report = bags.read_joint_series([bag])
                check_series(series)
                report.as_dict()
            self.run_case(target, read, lambda dest: Path(shutil.copytree(bag, dest)))

        self._hypothesis(strategy, case, batch, seed)

    def model_batch(self, seed_path, batch, seed):
        orig = seed_path.read_bytes()
        doc = yaml.safe_load(orig)
        path = self.work / "model.yaml"
        strategy = st.one_of(st.tuples(st.just("bytes"), st.lists(byte_ops(len(orig)), min_size=1, max_size=6)),
                             st.tuples(st.just("yaml"), yaml_ops(doc)))

        def case(kind, ops):
            path.write_bytes(mutate_bytes(orig, ops) if kind == "bytes" else mutate_yaml(doc, ops))
            self.run_case("model", lambda: check_model(mdl.load(path)),
                          lambda dest: Path(shutil.copy(path, dest.with_suffix(".yaml"))))

        self._hypothesis(strategy, case, batch, seed)

    @staticmethod
    def _hypothesis(strategy, case, batch, seed):
        @hseed(seed)
        @settings(max_examples=batch, deadline=None, database=None, phases=[Phase.generate],
                  suppress_health_check=list(HealthCheck), derandomize=False)
        @given(strategy)
        def run(x):
            case(*x)
        run()


def _alarm(signum, frame):
    raise Hang("case timed out")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=120.0, help="time budget (default 120 s)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the first batch (batch i uses seed + i)")
    ap.add_argument("--batch", type=int, default=50, help="hypothesis examples per batch (default 50)")
    ap.add_argument("--targets", default=",".join(TARGETS), help=f"comma-separated subset of {','.join(TARGETS)}")
    ap.add_argument("--out", default="build/fuzz", help="directory for crashing inputs (default build/fuzz)")
    ap.add_argument("--case-timeout", type=float, default=20.0, help="seconds before a case counts as a hang")
    ap.add_argument("--messages", type=int, default=0, metavar="N",
                    help="also print the N most frequent clean error lines per target")
    ap.add_argument("--memory-mb", type=int, default=4096, help="address-space limit of this process")
    a = ap.parse_args(argv)
    targets = [t.strip() for t in a.targets.split(",") if t.strip()]
    unknown = [t for t in targets if t not in TARGETS]
    if unknown or not targets:
        ap.error(f"unknown target {unknown[0] if unknown else ''!r}; known: {', '.join(TARGETS)}")
    if a.memory_mb > 0:
        lim = a.memory_mb << 20
        resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
    signal.signal(signal.SIGALRM, _alarm)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="reachset-fuzz-") as tmp:
        tmp = Path(tmp)
        (tmp / "seeds").mkdir()
        (tmp / "work").mkdir()
        seeds = make_seed_bags(tmp / "seeds")
        seed_models = make_seed_models(tmp / "seeds")
        fz = Fuzzer(tmp / "work", out, a.case_timeout)
        t0 = time.perf_counter()
        i = 0
        while time.perf_counter() - t0 < a.seconds:
            target = targets[i % len(targets)]
            if target == "model":
                fz.model_batch(seed_models[(i // len(targets)) % len(seed_models)], a.batch, a.seed + i)
            else:
                fz.bag_batch(target, seeds[target], a.batch, a.seed + i)
            i += 1
        dur = time.perf_counter() - t0
    total = sum(fz.cases.values())
    print(f"{total} cases in {dur:.0f} s ({total / dur:.0f}/s), {i} batches, seeds {a.seed}..{a.seed + i - 1}")
    for t in targets:
        print(f"  {t:9s} {fz.cases[t]:7d} cases: {fz.clean[t]:7d} clean errors, {fz.accepted[t]:7d} accepted, "
              f"{fz.crash_cases[t]} crashed")
        for msg, n in fz.messages[t].most_common(a.messages):
            print(f"      {n:6d}  {msg}")
    hangs = sum(1 for s in fz.crashes if s[1] == "Hang")
    print(f"crashes: {len(fz.crashes) - hangs} distinct, hangs: {hangs}")
    for (target, kind, where), (_, dest, _) in fz.crashes.items():
        print(f"  {target}: {kind} at {where} (input: {dest})")
    return 1 if fz.crashes else 0


if __name__ == "__main__":
    sys.exit(main())
