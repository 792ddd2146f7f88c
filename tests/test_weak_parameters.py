"""Weakly determined parameters are warned about by one rule on every machine (issue 36 item 3).

Before, only bed-probe files and fits of several files named the parameters their data
determine loosely; a tracker, pose, ballbar, dial or constraint-link fit of one file said
nothing, however large the standard deviations. Every calibration now ends with the same rule
(:mod:`pkmcal.identifiability.determination`: a standard deviation beyond 1/2500 of the machine's
size at its scale): the cases are generated from the registries (every instrument, every machine
type), simulated with ten to a hundred times the instruments' usual noise so the rule must fire,
and calibrated as ``pkmcal calibrate`` calibrates them.
"""

from __future__ import annotations

import numpy as np
import pytest

from pkmcal.calibration import calibrate
from pkmcal.errors import InputError
from pkmcal.identifiability.determination import (
    POOR_FRACTION,
    RULE_WORDS,
    poor_limit,
    poorly_determined,
)
from pkmcal.instruments.registry import INSTRUMENTS
from pkmcal.instruments.simulate import simulate_scenario
from pkmcal.instruments.tracker import as_tracker_data
from pkmcal.machines.registry import machine_formats

#: the noise of every simulated file (each instrument's --noise text): 100 um
NOISE = "100um"


def _machines() -> dict:
    return {kind: fmt.default() for kind, fmt in machine_formats().items() if fmt.default}


def _calibrated(machine, name):
    """A calibration of one simulated file of the instrument on the machine, or None where the
    instrument does not apply or its data cannot calibrate this machine alone."""
    inst = INSTRUMENTS[name]
    if inst.applies(machine) is not None:
        return None
    data, *_ = simulate_scenario(machine, name, rng=1, noise=inst.noise_arg(NOISE, machine))
    try:
        return calibrate(machine, as_tracker_data(data))      # points as tracker data
    except InputError:          # e.g. pair distances: fitted with other files only
        return None


@pytest.fixture(scope="module")
def cases():
    """``{(machine type, instrument): Calibration}``: every instrument on the first machine
    type it calibrates alone, and every machine type with the first instrument that does."""
    machines, out = _machines(), {}
    for name in INSTRUMENTS:
        for kind, machine in machines.items():
            cal = _calibrated(machine, name)
            if cal is not None:
                out[kind, name] = cal
                break
    for kind, machine in machines.items():
        if any(k == kind for k, _ in out):
            continue
        for name in INSTRUMENTS:
            cal = _calibrated(machine, name)
            if cal is not None:
                out[kind, name] = cal
                break
    return out


def test_the_cases_cover_every_machine_type_and_instrument(cases):
    kinds = {k for k, _ in cases}
    names = {n for _, n in cases}
    assert kinds == set(_machines())
    # the pair distances calibrate alone on a printer (two positions of the tool)
    assert names == set(INSTRUMENTS), set(INSTRUMENTS) - names


def test_one_rule_fires_on_every_machine_and_instrument(cases):
    for (kind, name), cal in cases.items():
        where = f"{kind} measured by {name}"
        machine = cal.machine               # the nominal: the file's size
        length = machine.characteristic_length()
        limit = poor_limit(length)
        section = cal.report["poorly_determined"]
        # the same rule, stated the same way, scaled by this machine's size
        assert section["rule"] == RULE_WORDS, where
        assert section["threshold_mm"] == pytest.approx(POOR_FRACTION * length * 1e3,
                                                        rel=1e-12), where
        assert section["characteristic_length_mm"] == pytest.approx(length * 1e3, rel=1e-12)
        listed = {p["name"] for p in section["parameters"]}
        assert listed, where                    # 100 um of noise: the rule fires
        # every listed parameter is beyond the limit, every free one beyond it is listed
        # (its marginal standard deviation; a weak direction can only add to it)
        res = cal.result
        n = len(machine.parameters)
        std = np.asarray(res.std, float)[:n]
        names = list(res.parameters.names)[:n]
        kinds = list(res.parameters.kinds)[:n]
        free = np.asarray(res.parameters.free, bool)[:n]
        size = np.where(np.array(kinds) == "length", std, std * length)
        assert {nm for nm, s, f in zip(names, size, free, strict=True) if f and s > limit} \
            <= listed, where
        fl = {"mm": 1e-3, "m": 1.0, "in": 0.0254, "inch": 0.0254}[cal.units["length"]]
        for p in section["parameters"]:
            si = p["std"] * (fl if p["kind"] == "length" else 1.0)
            assert (si if p["kind"] == "length" else si * length) > limit, (where, p)
        # what the library returns: the same parameters, largest first
        again = poorly_determined(res, n, length)
        assert [p.name for p in again] == [p["name"] for p in section["parameters"]], where
        # one warning, naming how many and the largest
        warned = [w for w in cal.warnings if "poorly determined" in w]
        assert len(warned) == 1, (where, warned)
        assert f"{len(listed)} parameter(s) poorly determined" in warned[0], where
        assert section["parameters"][0]["name"] in warned[0], where
        assert warned[0].startswith("<simulated>: "), where


def test_no_warning_below_the_limit(cases):
    """The rule is a threshold on the displacement at the machine's scale: a limit just above
    the largest names nothing, one just below names the largest alone."""
    (kind, name), cal = next(iter(cases.items()))
    res, machine = cal.result, cal.machine
    n, length = len(machine.parameters), machine.characteristic_length()
    poor = poorly_determined(res, n, length)
    largest = poor[0].size(length)
    assert poorly_determined(res, n, length, limit=largest * 1.001) == []
    assert [p.name for p in poorly_determined(res, n, length, limit=largest * 0.999)] \
        == [poor[0].name]


def test_the_html_report_states_the_rule(cases):
    from pkmcal.report.html import _instrument_sections

    cal = next(iter(cases.values()))
    page = _instrument_sections(cal.report)      # the section, without the plots
    assert "Poorly determined" in page and "1/2500 of the machine" in page
