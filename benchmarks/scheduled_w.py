"""Can the model extend itself? W scheduled on the measured speed (issue 37.4), measured.

Run: .venv/bin/python benchmarks/scheduled_w.py [--work DIR] [--verbose]

The disturbance set of each tick scaled by a known function of the data at that tick,
``w[t] in (1 + c |qd[t]|) W`` (qd: the envelope's backward difference,
:func:`reachset_ros.conformance.envelope.series_features`; 0 where not yet known), which the
monitor could check the same way online. Per joint, on the training runs of 1-80 (the bags of
``benchmarks/envelope.py``, built here or reused from ``--work``; never a held-out run), one LP
over z = [alpha_W (2), beta (2), alpha_V] >= 0 with beta = c alpha_W per generator (so c comes
out of the same LP), one Theorem-1 row per (test case, k) with zero centres:

    radW_k . alpha_W + S_k(t) . beta + radV alpha_V >= |y_a|,   S_k(t) = sum_{i<k} |C A^i G_W| |qd[t-1-i]|

(for a one-output plant this is Theorem 1's offset, paper eq. 13, with each step's W scaled);
cost: the radius of R_a[k] averaged over k and the training ticks. The baseline is the same
LP with beta = 0 (unscheduled W, the same cost). Solved by cutting planes (each k's largest
|y_a| first, then each k's most violated row until none is). Printed: the sets, c, and the
violating ticks (share of the paired ticks) at inflation 0 of every run of 81-100, of the
held-out runs 4-76 and of held-out run 80 (a workspace sweep, docs/real-data.md).
"""
import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))
from envelope import bags  # noqa: E402  (benchmarks/envelope.py: the protocol's bags)
from reachset_ros.bags import read_joint_series  # noqa: E402
from reachset_ros.bags.messages import JOINT_STATES, PLANT_INPUT  # noqa: E402
from reachset_ros.conformance import envelope as ev  # noqa: E402
from reachset_ros.conformance.kernels import sweep  # noqa: E402
from reachset_ros.robot import lwa4p  # noqa: E402


class Rows:
    """The plant's Theorem-1 radii per k for one-output plants with zero centres."""

    def __init__(self, model):
        self.model, p = model, model.plant
        self.K = model.horizon
        g, E = [], p.C.copy()
        for _ in range(self.K):
            g.append(np.abs(E @ p.Gw)[0])
            E = E @ p.A
        self.g = np.array(g)                                             # |C A^i G_W|
        self.radW = np.vstack([np.zeros(2), np.cumsum(self.g, axis=0)])  # sum_{i<k}
        self.radV = float(np.abs(p.Gv).sum())

    def speeds(self, s):
        """S[k] (T, 2), k = 0..K: sum_{i<k} |C A^i G_W| |qd[t-1-i]|."""
        a = np.nan_to_num(np.abs(ev.series_features(s.y, s.u, s.segments, s.dt)[:, 1]), nan=0.0)
        out = [np.zeros((len(a), 2))]
        for k in range(1, self.K + 1):
            sh = np.zeros(len(a))
            sh[k:] = a[:-k]
            out.append(out[-1] + self.g[k - 1][None, :] * sh[:, None])
        return out

    def deviations(self, s):
        """Per k: (measurement ticks t, |y_a|) of every test case."""
        per = {k: ([], []) for k in range(self.K + 1)}

        def visit(k, m, t, ya):
            per[k][0].append(t)
            per[k][1].append(np.abs(ya[0]))
        m = self.model
        sweep(m.plant, m.estimator, s.y, s.u, s.segments, self.K, visit)
        return {k: (np.concatenate(a), np.concatenate(b)) for k, (a, b) in per.items() if a}

    def lhs(self, k, S, t, z):
        return self.radW[k] @ z[:2] + S[k][t] @ z[2:4] + self.radV * z[4]


def fit(rows, R, S, scheduled):
    """z = [alpha_W, beta, alpha_V] of the LP (module docstring), by cutting planes."""
    from scipy.optimize import linprog
    K = rows.K
    mean_S = np.array([S[k].mean(axis=0) for k in range(K + 1)])
    cost = np.concatenate([rows.radW.sum(axis=0), mean_S.sum(axis=0) if scheduled else np.zeros(2),
                           [rows.radV * (K + 1)]])
    A_ub, b_ub = [], []

    def add(k, j):
        t, y = R[k]
        A_ub.append(-np.concatenate([rows.radW[k], S[k][t[j]] if scheduled else np.zeros(2), [rows.radV]]))
        b_ub.append(-y[j])
    for k in R:
        add(k, int(np.argmax(R[k][1])))
    bounds = [(0, None)] * 2 + ([(0, None)] * 2 if scheduled else [(0, 0)] * 2) + [(0, None)]
    for _ in range(500):
        z = linprog(cost, A_ub=np.array(A_ub), b_ub=np.array(b_ub), bounds=bounds, method="highs").x
        added = 0
        for k, (t, y) in R.items():
            viol = y - rows.lhs(k, S, t, z)
            j = int(np.argmax(viol))
            if viol[j] > 1e-12 * max(1.0, y[j]):
                add(k, j)
                added += 1
        if not added:
            return z * (1 + 1e-9)
    raise SystemExit("the cutting planes did not converge")


def violating(rows, s, z):
    """Violating ticks of ``s`` with the sets z (inflation 0) and its paired ticks."""
    R, S = rows.deviations(s), rows.speeds(s)
    bad = np.zeros(len(s.y), dtype=bool)
    for k, (t, y) in R.items():
        bad[t[y > rows.lhs(k, S, t, z)]] = True
    return int(bad.sum()), len(s.y)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=None, help="the LWA-4P recordings (default: the shipped ones)")
    ap.add_argument("--work", default=None, help="keep (and reuse) the bags and models here")
    a = ap.parse_args()
    data = str(lwa4p.recordings_dir(a.data))
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(a.work or tmp)
        d.mkdir(parents=True, exist_ok=True)
        model, paths = bags(data, d)
        rows = Rows(model)
        read = {k: read_joint_series([p], list(model.joints), model.plant.dt, (JOINT_STATES, PLANT_INPUT))[0]
                for k, p in paths.items()}
        print("| joint | unscheduled alpha_W, alpha_V | scheduled alpha_W, beta, alpha_V | c = beta / alpha_W | "
              "81-100: unscheduled / scheduled | held-out 4-76 | held-out run 80 |")
        print("|---|---|---|---|---|---|---|")
        for n in model.joints:
            R, S = rows.deviations(read["fit"][n]), rows.speeds(read["fit"][n])
            z0, z1 = fit(rows, R, S, False), fit(rows, R, S, True)
            cells = []
            for k in ("fam5", "held", "run80"):
                (v0, T), (v1, _) = violating(rows, read[k][n], z0), violating(rows, read[k][n], z1)
                cells.append(f"{v0} ({100 * v0 / T:.1f} %) / {v1} ({100 * v1 / T:.1f} %)")
            c = [z1[2 + i] / z1[i] if z1[i] > 0 else (float("inf") if z1[2 + i] > 0 else 0.0) for i in range(2)]
            print(f"| {n} | {np.round(z0[:2], 4).tolist()}, {z0[4]:.3g} | {np.round(z1[:2], 4).tolist()}, "
                  f"{np.round(z1[2:4], 4).tolist()}, {z1[4]:.3g} | {np.round(c, 3).tolist()} | " + " | ".join(cells)
                  + " |", flush=True)


if __name__ == "__main__":
    main()
