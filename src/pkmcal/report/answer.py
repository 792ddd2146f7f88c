"""The answer of a calibration in words (issue 36): the rows the console prints first and the
HTML report shows at its top, from the report's ``outcome`` section
(:func:`pkmcal.analysis.outcome.calibration_outcome`).

One unit per quantity (lengths of accuracy and residuals in um), three significant digits;
full precision stays in the JSON and the calibrated file.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from ..units import format_number

__all__ = ["DIGITS", "accuracy_unit", "answer_rows", "length_text", "number"]

#: significant digits of prose and tables
DIGITS = 3


def number(value, digits: int = DIGITS, sign: bool = False) -> str:
    """A number for people: ``digits`` significant digits, positional (never an exponent:
    0.0000431, 20200); ``n/a`` for None."""
    if value is None:
        return "n/a"
    value = float(value)
    if value != 0 and math.isfinite(value) and abs(value) < 1e-4:
        decimals = digits - 1 - math.floor(math.log10(abs(value)))
        return format(value, f"{'+' if sign else ''}.{decimals}f")
    return format_number(value, digits, sign=sign)


def accuracy_unit(*values_um) -> tuple[str, float]:
    """``(unit, factor from um)`` of the accuracy figures: um, the unit of every residual on
    the page (one unit per quantity: a held-out RMS in the answer and under Held-out
    validation reads the same)."""
    return "um", 1.0


def length_text(value_um, unit: str, f: float, sign: bool = False) -> str:
    """A length in um shown in ``unit`` (``f`` from :func:`accuracy_unit`)."""
    return "n/a" if value_um is None else f"{number(value_um * f, sign=sign)} {unit}"


def _change_text(c: Mapping) -> str:
    """``name -> value (change +x +- std unit)``: the change and its std in one unit."""
    unit = c.get("unit", "")
    std = c.get("std")
    text = (f"{c['name']} {c['before']:.6f} -> {c['after']:.6f} {unit} "
            f"(change {number(c['change'], sign=True)}")
    return text + (f" +- {number(std)} {unit})" if std is not None else ")")


def answer_rows(outcome: Mapping) -> list[tuple[str, str]]:
    """``(label, text)`` rows of the answer: verdict, accuracy before and after, held-out rows,
    what changed, the next commands.

    Parameters
    ----------
    outcome : mapping
        The report's ``outcome`` section.

    Returns
    -------
    list of (str, str)
        In the order shown.
    """
    rows = [("verdict", outcome["verdict"]["headline"])]
    acc = outcome.get("accuracy") or {}
    b, a = acc.get("before") or {}, acc.get("after") or {}
    if b.get("rms") is not None or a.get("rms") is not None:
        unit, f = accuracy_unit(b.get("rms"), b.get("max"), a.get("rms"), a.get("max"))
        text = (f"{acc['quantity']} over {acc['where']}: RMS "
                f"{length_text(b.get('rms'), unit, f)} with the machine file's values -> "
                f"{length_text(a.get('rms'), unit, f)} calibrated (1 sigma); largest "
                f"{length_text(b.get('max'), unit, f)} -> {length_text(a.get('max'), unit, f)}")
        if b.get("std") is not None:
            text += (f"; the before figure is known to +- {length_text(b['std'], unit, f)}"
                     " (the calibrated model's uncertainty)")
        if b.get("lowest") is not None:
            text += (f"; range with the values in force {length_text(b['lowest'], unit, f, True)}"
                     f" .. {length_text(b['highest'], unit, f, True)}")
        rows.append(("accuracy (predicted)", text))
    elif acc.get("why"):
        rows.append(("accuracy", acc["why"]))
    held = outcome.get("held_out_rows")
    if held:
        for h in held.get("files") or [held]:
            unit, f = accuracy_unit(h.get("before_rms"), h.get("after_rms"))
            rows.append(("held-out rows", f"{h.get('rows')} rows not used in the fit: RMS "
                         f"{length_text(h.get('before_rms'), unit, f)} -> "
                         f"{length_text(h.get('after_rms'), unit, f)} ({h.get('of', '')})"))
    same = outcome.get("same_as_running") or {}
    changes = outcome.get("changes") or []
    if same.get("same"):
        rows.append(("what changed", "nothing beyond the uncertainty: the calibrated values "
                     "equal what the machine runs (largest change "
                     f"{number(same['largest_change_over_std'])} standard deviations)"))
    elif changes:
        held = changes[0].get("held")
        rows.append(("what changed", "; ".join(_change_text(c) for c in changes[:3])
                     + (f" (with {', '.join(held)} held at the machine file's values: the "
                        "data fix the others only relative to them)" if held else "")))
    firmware = outcome.get("firmware") or []
    if firmware and not same.get("same"):
        shown = sorted(firmware, key=lambda c: -abs(c["change"]) * (1.0 if c["unit"] != "deg"
                                                                     else 10.0))[:3]
        rows.append(("firmware values", "; ".join(
            f"{c['name']} {c['before']:.6f} -> {c['after']:.6f} {c['unit']}" for c in shown)))
    for i, step in enumerate(outcome.get("next") or []):
        rows.append(("next" if i == 0 else "", f"{step['command']}  ({step['why']})"))
    return rows
