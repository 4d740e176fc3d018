"""Cost of one 4 ms step of the simulated arm (1 kHz RK4 physics, realistic configuration).

Run: .venv/bin/python benchmarks/bench_simulator.py
"""
import time

import numpy as np

from reachset_ros import robot as rb
from reachset_ros.sim import simulator as sim
from reachset_ros.sim.reference import ReferenceConfig


def main(n=2500):
    model = rb.load_model()
    data = rb.create_data(model)
    arm = sim.SimulatedArm(sim.SimConfig.realistic(model), seed=0)
    rc = ReferenceConfig()
    q0 = 0.5 * (rc.q_min + rc.q_max)
    m = arm.reset(q0)
    d = np.empty(n)
    for k in range(n):
        q_d = q0 + 0.2 * np.sin(2 * np.pi * 0.25 * k * 0.004)
        u = 100.0 * (q_d - m.q_measured) - 20.0 * m.qd_measured
        tau = rb.feedback_linearization(model, data, m.q_measured, m.qd_measured, u)
        t0 = time.perf_counter()
        m = arm.step(tau)
        d[k] = time.perf_counter() - t0
    d *= 1e3
    print(f"simulator step (4 ms of 6-joint physics, {arm.state.substeps} RK4 substeps): "
          f"mean {d.mean():.3f} ms, p99 {np.percentile(d, 99):.3f} ms, max {d.max():.3f} ms over {n} steps")


if __name__ == "__main__":
    main()
