"""The guarantee's rows (reachset_ros.guarantees) and docs/theory.md's table agree, and a
refusal names the row it protects (issue 34: "a model or gain change that would void any
table row is refused with a message naming the row")."""
import re
from pathlib import Path

import pytest

from reachset_ros import guarantees
from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.conformance.kernels import require_minimum_horizon
from reachset_ros.errors import ReachsetError, first_line
from reachset_ros.systems.gains import Gains, certify_pair
from reachset_ros.systems.plant import lwa4p_joint_plant

THEORY = Path(__file__).resolve().parent.parent / "docs" / "theory.md"
PLANT = lwa4p_joint_plant()


def _glance_rows():
    """id -> the row's cells of docs/theory.md's table "Assumptions at a glance"."""
    text = THEORY.read_text()
    start = text.index("## Assumptions at a glance")
    end = text.find("\n## ", start + 1)
    rows = {}
    for line in text[start:end if end > 0 else None].splitlines():
        m = re.match(r"\|\s*(G\d+)\s*\|", line)
        if m:
            cells = re.split(r"(?<!\\)\|", line.strip().strip("|"))       # a cell may hold an escaped \|
            rows[m.group(1)] = [c.strip().replace("\\|", "|") for c in cells]
    return rows


def test_the_docs_table_has_exactly_the_rows_of_the_code():
    rows = _glance_rows()
    assert list(rows) == list(guarantees.ROWS)
    for rid, cells in rows.items():
        assert cells[1] == guarantees.ROWS[rid], f"{rid}: the table says {cells[1]!r}"
        assert "test/" in cells[-1], f"{rid}: no test shows it"
        assert any(c not in ("", "—") for c in cells[2:-1]), f"{rid}: nothing enforces it"


def test_a_refusal_is_one_line_ending_with_its_row():
    e = guarantees.refused("G7", "joint a: R*_u leaves U_p")
    assert isinstance(e, ReachsetError) and e.row == "G7"
    assert first_line(e) == f"joint a: R*_u leaves U_p [guarantee G7: {guarantees.ROWS['G7']}]"
    with pytest.raises(KeyError):
        guarantees.refused("G99", "no such row")


def test_a_horizon_below_the_minimum_names_row_g1():
    with pytest.raises(guarantees.GuaranteeRefused, match=r"\[guarantee G1: ") as e:
        require_minimum_horizon(PLANT, 0)
    assert e.value.row == "G1"


def test_gains_whose_r_u_leaves_u_p_name_row_g7_and_a_wrong_dt_row_g4():
    js = mdl.JointSets((0.0348, 3.59), (3.49e-5,), (0.0,) * 5, (0.0,), 0, 125,
                       gains={**Gains(omega=24.40, zeta=0.96, h1=15.0, h2=30.0).model_dict(), "u_max": 26.0,
                              "u_ff": 2.0}, extra={"reference_error": {"u_e_ff": [0.0, 0.0]}})
    model = mdl.ConformanceModel(PLANT, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 125,
                                 {"arm_1_joint": js}, 1.0)      # Table II at inflation 1: R_u 29.35 > 26
    g = Gains.from_model(js.gains)
    with pytest.raises(guarantees.GuaranteeRefused, match=r"R\*_u = .* \[guarantee G7: ") as e:
        certify_pair({"arm_1_joint": g}, model, [26.0], 2.0, 0.004)
    assert e.value.row == "G7"
    with pytest.raises(guarantees.GuaranteeRefused, match=r"dt .* \[guarantee G4: "):
        certify_pair({"arm_1_joint": g}, model, [26.0], 2.0, 0.002)
