"""An instrument's calibration flow lives in its module (issue 38): the calibration layer
dispatches every instrument that brings a flow through the registry (its options:
tests/test_instrument_options.py)."""

from __future__ import annotations

from pkmcal.calibration.flows import calibrate_flow, check_instrument, joint_flow
from pkmcal.calibration.kinds import KINDS, all_kinds
from pkmcal.instruments.base import Instrument
from pkmcal.instruments.registry import INSTRUMENTS

all_kinds()
FLOWS = [inst for inst in INSTRUMENTS.values() if inst.has_flow]
IDS = [inst.name for inst in FLOWS]


def test_the_older_instruments_bring_their_flows_and_the_registry_dispatches_them():
    assert {"tracker", "pose", "distance", "constraint-link", "probe"} <= set(IDS)
    for inst in FLOWS:
        kind = KINDS[inst.name]
        assert kind.calibrate.func is calibrate_flow, inst.name
        assert kind.calibrate.keywords == {"inst": inst}
        assert kind.check_options.func is check_instrument
        assert kind.check_options.keywords == {"inst": inst}


def test_the_instruments_bring_their_parts_of_a_fit_of_several_files():
    """The joint fit's part of every instrument with a flow of its own that combines is its
    module's (Instrument.joint_part), dispatched through the registry (run.py names none)."""
    combining = [inst for inst in FLOWS if not inst.joint_refusal]
    assert {"tracker", "distance", "probe"} <= {inst.name for inst in combining}
    for inst in combining:
        owner = next(c for c in type(inst).__mro__ if "joint_part" in vars(c))
        assert owner is not Instrument and owner.__module__ == type(inst).__module__, inst.name
        kind = KINDS[inst.name]
        assert kind.joint.func is joint_flow and kind.joint.keywords == {"inst": inst}
