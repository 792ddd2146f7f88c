"""The runnable example scripts (examples/scripts) run and show what they promise."""

from __future__ import annotations

import importlib.util
from pathlib import Path

SCRIPTS = Path(__file__).resolve().parents[1] / "examples" / "scripts"


def _load(name):
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_hexaslide_script(capsys):
    out = _load("hexaslide_self_calibration").main()
    assert out["predicted"] < out["random_median"]
    assert out["after"] < 0.01 * out["before"]
    assert "wrote" in capsys.readouterr().out


def test_delta_script(capsys):
    out = _load("delta_tracker_calibration").main()
    assert out["after"] < 0.02 * out["before"]
    assert "translation of the platform frame" in capsys.readouterr().out
