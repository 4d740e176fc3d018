"""Simulated multi-joint recordings for the benchmarks, cached under benchmarks/.cache/.

The per-joint plant of the paper's Appendix A (:func:`reachset_ros.systems.plant.lwa4p_joint_plant`)
runs in closed loop (a PD law around a slow sine, as ``test/conformance/test_conformance.py``'s
``simulate``) with bounded random process disturbances and measurement noise, all joints
at once (vectorised across joints). The bag holds ``/joint_states`` (position, velocity,
effort of every joint) and ``/plant_input`` at 250 Hz, CDR-encoded here with ``struct``
and written with :class:`reachset_ros.bags.BagWriter` (rosbags, MCAP).

Syntax::

    path = ensure_bag("sim6_33min", ticks=495_000)   # generated once, then reused
"""
from __future__ import annotations

import struct
import sys
import time
from pathlib import Path

import numpy as np

from reachset_ros import bags
from reachset_ros.systems.plant import lwa4p_joint_plant

CACHE = Path(__file__).resolve().parent / ".cache"
JOINTS = tuple(f"arm_{i}_joint" for i in range(1, 7))
T0 = 1_700_000_000_000_000_000
DT_NS = 4_000_000
ALPHA_W = np.array([0.03, 3.0])
ALPHA_V = np.array([3.5e-5])
VERSION = 1  # bump when the generator changes; the cache key includes it


def simulate_joints(ticks, joints=len(JOINTS), seed=0, gain=(100.0, 20.0)):
    """Closed-loop simulation of ``joints`` independent joints; returns y, u of shape (T, J)."""
    p = lwa4p_joint_plant()
    rng = np.random.default_rng(seed)
    J = joints
    amp = 1.0 + 0.5 * np.arange(J)                # per joint reference amplitude, rad/s^2
    freq = 0.003 * (1.0 + 0.25 * np.arange(J))    # per tick
    w = rng.uniform(-1, 1, (ticks, 2, J)) * ALPHA_W[None, :, None]
    v = rng.uniform(-1, 1, (ticks, J)) * ALPHA_V[0]
    ref = amp[None, :] * np.sin(freq[None, :] * np.arange(ticks)[:, None])
    A, B, Gw = np.asarray(p.A), np.asarray(p.B), np.asarray(p.Gw)
    X = np.zeros((5, J))
    y, u = np.empty((ticks, J)), np.empty((ticks, J))
    g0, g1 = gain
    for k in range(ticks):
        y[k] = X[0] + v[k]
        uk = ref[k] - g0 * X[1] - g1 * X[2]
        u[k] = uk
        X = A @ X + B * uk + Gw @ w[k]
    return y, u


# ------------------------------------------------------------------ CDR encoding (little endian)
def _string(s: bytes, pos: int):
    pad = (-pos) % 4
    return b"\0" * pad + struct.pack("<I", len(s) + 1) + s + b"\0"


def _prefix(names):
    """Bytes of the body after the stamp up to the first float sequence's count (inclusive)."""
    out = bytearray(_string(b"", 8))            # frame_id ""
    pos = 8 + len(out)
    out += b"\0" * ((-pos) % 4) + struct.pack("<I", len(names))
    for n in names:
        s = _string(n.encode(), 8 + len(out))
        out += s
    return bytes(out)


def _float_seq(values, pos):
    """A float64 sequence at body offset ``pos`` (count aligned 4, data aligned 8 if any)."""
    head = b"\0" * ((-pos) % 4) + struct.pack("<I", len(values))
    pos += len(head)
    pad = b"\0" * ((-pos) % 8) if len(values) else b""
    return head + pad + np.asarray(values, "<f8").tobytes()


def encode(stamp_ns, names, *seqs):
    """CDR bytes of a JointState (seqs = position, velocity, effort) or PlantInput (acceleration)."""
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    body = bytearray(struct.pack("<iI", sec, nsec))
    body += _prefix(names)
    for s in seqs:
        body += _float_seq(s, len(body))
    return b"\x00\x01\x00\x00" + bytes(body)


def write_bag(path, y, u, names=JOINTS, t0=T0, storage="mcap"):
    """A rosbag2 (MCAP or sqlite3) with /joint_states and /plant_input of the arrays y, u (T, J)."""
    T = len(y)
    vel = np.vstack([np.zeros((1, y.shape[1])), np.diff(y, axis=0) / (DT_NS * 1e-9)])
    eff = np.zeros(y.shape[1])
    with bags.BagWriter(path, storage=storage) as w:
        for k in range(T):
            st = t0 + k * DT_NS
            w.write_raw(bags.JOINT_STATES, encode(st, names, y[k], vel[k], eff), st + 300_000,
                        bags.JOINT_STATE_TYPE)
            w.write_raw(bags.PLANT_INPUT, encode(st, names, u[k]), st + 600_000, bags.PLANT_INPUT_TYPE)


def ensure_bag(name, ticks, seed=0, first=None, storage="mcap"):
    """Path of the cached bag ``name`` (``ticks`` ticks, 6 joints); generated when missing.

    ``first``: write only the first ``first`` ticks of the simulation (a shorter bag of the
    same data); ``storage``: ``"mcap"`` or ``"sqlite3"``.
    """
    leaf = (f"first{first}" if first else "bag") + ("" if storage == "mcap" else f"_{storage}")
    path = CACHE / f"{name}_v{VERSION}_s{seed}_T{ticks}" / leaf
    if path.is_dir():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    npz = path.parent / "sim.npz"
    if npz.exists():
        d = np.load(npz)
        y, u = d["y"], d["u"]
    else:
        y, u = simulate_joints(ticks, seed=seed)
        np.savez(npz, y=y, u=u)
    n = first or ticks
    write_bag(path, y[:n], u[:n], storage=storage)
    print(f"[simbag] generated {path} ({n} ticks) in {time.perf_counter() - t:.1f} s", file=sys.stderr)
    return path
