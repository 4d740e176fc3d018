"""config/lwa4p.yaml: every key is a declared parameter of its node and loads as given."""
import importlib
from pathlib import Path

import pytest
import rclpy
import yaml

CONFIG = Path(__file__).resolve().parents[2] / "config" / "lwa4p.yaml"
CLASSES = {"sim_node": "SimNode", "reference_node": "ReferenceNode", "observer_node": "ObserverNode",
           "controller_node": "ControllerNode", "monitor_node": "MonitorNode", "synthesis_node": "SynthesisNode",
           "recorder_node": "RecorderNode"}


def test_every_node_has_a_section():
    assert set(yaml.safe_load(CONFIG.read_text())) == set(CLASSES)


@pytest.mark.dds
@pytest.mark.parametrize("name", sorted(CLASSES))
def test_params_file_loads_into_the_node(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)                       # nodes may create their default directories
    expected = yaml.safe_load(CONFIG.read_text())[name]["ros__parameters"]
    extra = []
    if name == "monitor_node":      # issue 34.1: a monitor without a model does not start
        from helpers import write_model
        expected = {**expected, "model_file": str(write_model(tmp_path / "m.yaml"))}
        extra = ["-p", f"model_file:={expected['model_file']}"]
    rclpy.init(args=["--ros-args", "--params-file", str(CONFIG), *extra])
    try:
        cls = getattr(importlib.import_module(f"reachset_ros.nodes.{name}"), CLASSES[name])
        node = cls()
        try:
            for key, value in expected.items():
                assert node.has_parameter(key), f"{name}: {key} is not declared"
                got = node.get_parameter(key).value
                assert (list(got) if isinstance(got, (list, tuple)) or hasattr(got, "tolist") else got) == value, key
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()
