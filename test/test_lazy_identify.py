"""Start-up of ``identify`` and ``replay`` (issue 38.2, 38.3): what they import is what they use.
Import sets, not times (``benchmarks/identify_replay.py`` measures the times)."""
import numpy as np

from reachset_ros import bags

from test_lazy import imported_after

#: rosbags' message stores: ``bags.typestore()`` loads them (0.1 s); the fast MCAP reader does not need them
STORES = "rosbags.typesys.stores.ros2_jazzy"


def test_identify_imports_no_fleet_without_workers():
    """The fleet (Dask tasks, and through them the synthesis' modules, 0.1 s) is imported by
    ``--workers``/``--scheduler`` only."""
    mods = imported_after("from reachset_ros import cli\ncli.build_parser(only='identify')\n"
                          "import reachset_ros.workflows.identify")
    assert "reachset_ros.workflows.identify" in mods
    assert not {m for m in mods if m.startswith(("reachset_ros.fleet", "reachset_ros.synthesis", "dask"))}


def test_reading_a_bag_without_references_loads_no_message_store(tmp_path):
    """``identify`` looks for ``/reference`` (the class' coverage); a bag without the topic is
    answered from its metadata, without rosbags' message stores."""
    bag = tmp_path / "b"
    with bags.BagWriter(bag) as w:
        for i in range(40):
            st = 1_700_000_000_000_000_000 + 4_000_000 * i
            w.write(bags.JOINT_STATES, bags.joint_state(st, ["j"], [np.sin(0.1 * i)]), st)
            w.write(bags.PLANT_INPUT, bags.plant_input(st, ["j"], [0.0]), st)
    mods = imported_after(f"from reachset_ros.bags import read_joint_series\n"
                          f"from reachset_ros.bags.references import read_references\n"
                          f"s, _ = read_joint_series([{str(bag)!r}], None, 0.004)\n"
                          f"assert len(s['j'].y) == 40\n"
                          f"assert read_references([{str(bag)!r}], ['j'], 0.004) == {{}}")
    assert "reachset_ros.bags.decoded" in mods and STORES not in mods
