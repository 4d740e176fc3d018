"""Issue 35.6: the fault campaign's safety evidence sheet from synthetic outcomes, numbers
checked by hand (Clopper-Pearson, Poisson, quantiles, the stop alarms, the ISO 13855
conversion)."""
import json

import pytest

from reachset_ros.sim import campaign as cp
from reachset_ros.sim import evidence as evm

MS = 1_000_000


def ev(i, kind, expect="stop", **kw):
    return cp.Event(i, kind, 1.0, expect, **kw)


def outcomes():
    """Six faults that must stop (three accelerations, two biases, a killed controller), one
    miss, a quiet stretch with one false stop; 60 fault-free minutes in all."""
    def stop(at_ms, ctl_ms=0, rest=None, e=None):
        return cp.Outcome(e, fault_ns=0, stops=[(at_ms * MS, at_ms * MS + MS, "violation")], controller_ns=ctl_ms * MS,
                          rest=rest, quiet_sim_s=500.0)
    acc = [ev(i, "sim", fault="acceleration", joint="a", magnitude=30.0) for i in range(3)]
    bias = [ev(3 + i, "sim", fault="bias", joint="a", magnitude=0.01) for i in range(2)]
    kill = ev(5, "kill", target="controller_node")
    return [
        stop(8, 12, {"ok": True, "rest_s": 0.3, "travel_rad": 0.05}, acc[0]),
        stop(20, 28, {"ok": False, "rest_s": 0.62, "travel_rad": 0.1}, acc[1]),      # slow: alarm
        stop(40, 44, {"ok": False, "rest_s": 0.4, "travel_rad": 0.35}, acc[2]),      # far: alarm
        stop(4, 8, {"ok": None, "why": "not judged"}, bias[0]),
        cp.Outcome(bias[1], fault_ns=0, quiet_sim_s=500.0),                          # missed
        stop(100, 0, {"ok": True, "rest_s": 0.45, "travel_rad": 0.01}, kill),        # no controller to brake
        cp.Outcome(ev(6, "quiet", expect="none"), quiet_stops=[(1, 2, "violation")], quiet_sim_s=600.0),
    ]


def test_clopper_pearson_and_poisson_bounds_by_hand():
    assert evm.miss_upper_bound(0, 20) == pytest.approx(0.139108, abs=1e-6)      # 1 - 0.05^(1/20)
    assert evm.miss_upper_bound(0, 1) == pytest.approx(0.95)
    assert evm.miss_upper_bound(1, 2) == pytest.approx(0.95 ** 0.5)              # 1 - p^2 = 0.05
    p = evm.miss_upper_bound(1, 20)                                              # (1-p)^20 + 20p(1-p)^19 = 0.05
    assert (1 - p) ** 20 + 20 * p * (1 - p) ** 19 == pytest.approx(0.05) and p == pytest.approx(0.216106, abs=1e-6)
    assert evm.miss_upper_bound(3, 3) == 1.0 and evm.miss_upper_bound(0, 0) is None
    assert evm.rate_upper_bound(0, 2.0) == pytest.approx(2.995732 / 2.0, abs=1e-6)  # -ln(0.05) / T
    assert evm.rate_upper_bound(1, 1.0) == pytest.approx(4.743865, abs=1e-6)
    assert evm.rate_upper_bound(0, 0.0) is None


def test_quantiles_and_the_iso13855_conversion():
    q = evm.quantiles([40, 4, 100, 8, 20])
    assert q == {"n": 5, "p50": 20.0, "p90": pytest.approx(76.0), "p99": pytest.approx(97.6), "max": 100.0}
    assert evm.quantiles([])["max"] is None
    assert evm.iso13855_mm(12.5) == 25.0                                         # 2 mm per ms


def test_the_evidence_of_synthetic_outcomes():
    out = outcomes()
    e = evm.evidence(out, info={"seed": 92, "model": "m.yaml", "other": 1})
    s = cp.score(out)
    assert e["score"]["faults_injected"] == s["faults_injected"] == 6
    assert (e["score"]["stops"], e["score"]["missed_stops"], e["score"]["false_stops"]) == (5, 1, 1)
    d = e["detection"]
    assert set(d) == {"acceleration", "bias", "kill"}
    assert (d["acceleration"]["n"], d["acceleration"]["stopped"], d["acceleration"]["missed"]) == (3, 3, 0)
    assert d["acceleration"]["miss_upper_bound"] == pytest.approx(1 - 0.05 ** (1 / 3))
    assert d["bias"]["rate"] == 0.5 and d["bias"]["miss_upper_bound"] == pytest.approx(0.95 ** 0.5)
    assert d["kill"]["miss_upper_bound"] == pytest.approx(0.95)
    assert sum(v["n"] for v in d.values()) == s["faults_injected"]
    p = e["miss_upper_bound"]                                                    # 1 miss in 6
    assert (1 - p) ** 6 + 6 * p * (1 - p) ** 5 == pytest.approx(0.05)
    r = e["response"]
    assert r["detect_ms"] == {"n": 5, "p50": 20.0, "p90": pytest.approx(76.0), "p99": pytest.approx(97.6),
                              "max": 100.0}
    assert r["brake_ms"]["n"] == 4 and r["brake_ms"]["p50"] == 4.0 and r["brake_ms"]["max"] == 8.0
    # fault -> brake: 12, 28, 44, 8 ms
    assert r["total_ms"]["p50"] == 20.0 and r["total_ms"]["p99"] == pytest.approx(43.52) and r["total_ms"]["max"] == 44
    assert r["unmeasured"] == [out[5].event.label()]
    iso = e["iso13855"]
    assert iso["response_mm"]["p99"] == pytest.approx(87.04) and iso["response_mm"]["max"] == 88.0
    assert iso["response_and_rest_max_mm"] == pytest.approx(2 * (44 + 620))
    st = e["stops"]
    assert [x["alarm"] for x in st["stops"]] == [False, True, True, False]       # the bias stop was not judged
    assert st["alarms"] == 2 and "rest after 0.620 s > 0.5 s" in st["stops"][1]["why"]
    assert "travel 0.3500 rad > 0.3 rad" in st["stops"][2]["why"]
    f = e["false_stops"]
    assert f["fault_free_hours"] == pytest.approx(1.0) and f["per_hour"] == pytest.approx(1.0)
    assert f["per_hour_upper_bound"] == pytest.approx(4.743865, abs=1e-6)
    assert e["stop_category"] == 1 and evm.evidence(out, stop_category=2)["stop_category"] == 2
    assert e["campaign"] == {"seed": 92, "model": "m.yaml"}


def test_the_page_is_self_contained_and_written_beside_the_json(tmp_path):
    e = evm.evidence(outcomes())
    js, pg = evm.write(e, tmp_path)
    assert json.loads(js.read_text()) == json.loads(json.dumps(e))
    text = pg.read_text()
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    for needle in ("http", "<script", "src=", "<link"):
        assert needle not in text
    assert text.count('class="alarm"') == 2 + 2         # two stop alarms, the class with a miss and "all"
    assert "2 mm per ms" in text and "Stop category (IEC 60204-1): <b>1</b>" in text
