"""How small can a model's sets make a sensor bias's first check? (issue 35, a bias's half).

A bias b that starts at sample s changes every sample from s on by b. The test case that starts
on the sample before it sees the deviation b at its first step (k = 1, the deviation of
y[s] = q[s-1] + v[s] from the estimate of q[s-1]). Its bound there is, per unit of inflation
(1 + eps), the worst case over the model's noise and disturbance bounds of

    q[s-1] - q_hat[s-1] + v[s],    q_hat[s-1] = sum_j a_j y[s-1-N+j] + (input terms),

where the estimate is exact on noise-free model data (every estimator here is). That is
alpha_V (1 + sum_j |a_j|) plus the disturbances over the window through the estimate. This
script minimises it over all such linear estimators of windows 1..N (scipy's HiGHS LP) with
the model's own alpha_W, alpha_V and inflation, and prints it beside the bound the model's own
estimator gives (Theorem 1's d+_1 of the model, ``MonitorModel.dp_vec[1]``).

It is a floor for that one test case and these sets only: a different estimator changes the
identified sets too, and a test case that starts on the step counts as well
(:func:`reachset_ros.sim.detectability.sets_limit` takes every test case). The model must be
identified with ``--initial-state-set``: only then is alpha_V a bound of each sample's noise
(otherwise the estimator's error is charged to W and V, and the script refuses it).

Run: ``.venv/bin/python benchmarks/bias_floor.py MODEL.yaml [--windows 8]``.
"""
import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import linprog

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from reachset_ros.conformance import model as mdl  # noqa: E402
from reachset_ros.conformance.monitor import MonitorModel  # noqa: E402


def window_maps(h, N):
    """Coefficients of the window's positions y[s-1-N..s-1] = q[t0..t0+N] and of q[s-1] = q[t0+N+1]
    over [q[t0], qdot[t0], w_1[t0], w_2[t0], ..., w_1[t0+N], w_2[t0+N]] (the per-joint LWA-4P plant's
    generators: a velocity one adding dt to q, an acceleration one adding dt^2/2 to q and dt to qdot)."""
    dim = 2 + 2 * (N + 1)
    q, qd = np.zeros(dim), np.zeros(dim)
    q[0], qd[1] = 1.0, 1.0
    rows = []
    for t in range(N + 2):
        rows.append(q.copy())
        if t == N + 1:
            break
        q = q + h * qd
        q[2 + 2 * t] += h
        q[3 + 2 * t] += 0.5 * h * h
        qd = qd.copy()
        qd[3 + 2 * t] += h
    return np.array(rows[:-1]), rows[-1]


def floor(h, alpha_w, alpha_v, N):
    """min over a of alpha_V (1 + sum |a|) + sum_g alpha_W[g] |w-coefficient of the error| (LP)."""
    Y, target = window_maps(h, N)
    n_a, n_w = N + 1, 2 * (N + 1)
    aw = np.tile(np.asarray(alpha_w, float), N + 1)
    # variables [a (n_a), ta (n_a), tw (n_w)]; error coefficients e = target - a @ Y
    c = np.concatenate([np.zeros(n_a), np.full(n_a, alpha_v), aw])
    A_ub, b_ub = [], []
    for i in range(n_a):                       # |a_i| <= ta_i
        for sgn in (1, -1):
            r = np.zeros(2 * n_a + n_w)
            r[i], r[n_a + i] = sgn, -1
            A_ub.append(r)
            b_ub.append(0.0)
    for g in range(n_w):                       # |target_g - a @ Y[:, g]| <= tw_g
        col = Y[:, 2 + g]
        for sgn in (1, -1):
            r = np.zeros(2 * n_a + n_w)
            r[:n_a] = -sgn * col
            r[2 * n_a + g] = -1
            A_ub.append(r)
            b_ub.append(-sgn * target[2 + g])
    A_eq = np.zeros((2, 2 * n_a + n_w))        # exact on the model: no q[t0], qdot[t0] left
    A_eq[:, :n_a] = Y[:, :2].T
    res = linprog(c, A_ub=np.array(A_ub), b_ub=np.array(b_ub), A_eq=A_eq, b_eq=target[:2], bounds=(None, None),
                  method="highs")
    if not res.success:
        raise RuntimeError(res.message)
    return res.fun + alpha_v, res.x[:n_a]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("--windows", type=int, default=8, help="largest window tried (samples - 1)")
    a = ap.parse_args(argv)
    m = mdl.load(a.model)
    if not m.initial_state_set:
        # without it the estimator's error is charged to W and V: alpha_V is no per-sample noise bound
        print(f"bias_floor.py: {a.model}: identified without --initial-state-set; its V also carries the "
              f"estimator's error, so it bounds no single sample's noise (identify with --initial-state-set)",
              file=sys.stderr)
        sys.exit(2)
    print(f"model {a.model}: estimator {m.estimator.as_dict()}, initial-state set {m.initial_state_set}")
    print("| joint | inflation | the model's d+_1, urad | floor over linear estimators, urad | its window, weights |")
    print("|---|---|---|---|---|")
    for j, js in m.joints.items():
        infl = m.joint_inflation(j)
        best = min((floor(m.plant.dt, js.alpha_w, js.alpha_v[0], N) + (N,) for N in range(1, a.windows + 1)),
                   key=lambda r: (round(r[0], 12), r[2]))          # ties: the shortest window
        dp1 = float(MonitorModel.from_model(m, j).dp_vec[1])
        w = ", ".join(f"{x + 0.0:.2f}" for x in np.round(best[1], 6))
        print(f"| {j} | {infl:g} | {1e6 * dp1:.0f} | {1e6 * (1 + infl) * best[0]:.0f} | {best[2]}: {w} |")


if __name__ == "__main__":
    main()
