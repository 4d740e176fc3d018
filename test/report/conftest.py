"""The report tests' recordings and model, made once per session (report_case.make_case)."""
import pytest

from report_case import make_case


@pytest.fixture(scope="session")
def case(tmp_path_factory):
    return make_case(tmp_path_factory.mktemp("report"))
