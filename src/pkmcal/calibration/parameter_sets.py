"""Named parameter sets (``--parameters NAME``): a firmware's set, ``full``, what a machine
lists; a machine copy whose fixed flags are a set's."""

from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["apply_parameter_set", "parameter_set_names", "parameter_set_of"]


def _machines_with_sets() -> list[str]:
    """Machine types whose class has named parameter sets (``parameter_set``)."""
    from ..machines.base import Machine

    found, todo = set(), list(Machine.__subclasses__())
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        if getattr(cls, "kind", "") and (getattr(cls, "PARAMETER_SETS", None)
                                         or "parameter_set" in vars(cls)):
            found.add(cls.kind)
    return sorted(found)


def parameter_set_names(machine) -> list[str] | None:
    """The names of a machine's parameter sets, when it lists them (None: it does not).

    Parameters
    ----------
    machine : Machine
        The machine (``parameter_sets``: a list, a mapping or a method giving one).

    Returns
    -------
    list of str or None
        The names.
    """
    sets = getattr(machine, "parameter_sets", None)
    if callable(sets):
        sets = sets()
    if sets is None:
        own = getattr(machine, "PARAMETER_SETS", None)
        if own is None:
            return None
        return sorted(set(map(str, own)) | {"full"})
    return [str(k) for k in (sets.keys() if isinstance(sets, dict) else sets)]


def apply_parameter_set(machine, name: str):
    """A copy of ``machine`` whose fixed flags are those of its parameter set ``name``.

    Parameters
    ----------
    machine : Machine
        A machine with ``parameter_set(name) -> ParameterSet`` (e.g. a firmware's set).
    name : str
        The set's name (``--parameters``).

    Returns
    -------
    Machine
        The copy (values unchanged; parameters the set does not name are fixed).

    Raises
    ------
    InputError
        When the machine has no named sets (naming the machine types that have them) or
        none of this name (listing its sets).
    """
    method = getattr(machine, "parameter_set", None)
    kind = getattr(machine, "kind", "") or "machine"
    if not callable(method):
        having = _machines_with_sets()
        raise InputError(f"--parameters {name}: a {kind} has no named parameter sets ("
                         + (f"machines with them: {', '.join(having)}" if having else
                            "no machine type of this version has them") + ")")
    names = parameter_set_names(machine)
    if names == ["full"] and name != "full":
        having = _machines_with_sets()
        raise InputError(f"--parameters {name}: a {kind} has no named parameter sets besides "
                         "full (every parameter free) ("
                         + (f"machines with them: {', '.join(having)}" if having else
                            "no machine type of this version has them") + ")")
    listing = f"; its sets: {', '.join(names)}" if names else ""
    if names is not None and name not in names:
        raise InputError(f"--parameters {name}: no parameter set of that name for this "
                         f"{kind}{listing}")
    try:
        chosen = method(name)
    except (KeyError, ValueError, InputError) as exc:
        text = str(exc).strip("'\"")
        raise InputError(f"--parameters {name}: no parameter set of that name for this "
                         f"{kind}{listing or (': ' + text if text else '')}") from None
    mp = machine.parameters
    if tuple(chosen.names) == tuple(mp.names):
        fixed = np.asarray(chosen.fixed, bool)
    else:
        lookup = dict(zip(chosen.names, np.asarray(chosen.fixed, bool), strict=True))
        fixed = np.array([lookup.get(n, True) for n in mp.names], bool)
    new = machine.with_parameters(mp.values)
    new.parameters = mp.with_fixed_mask(fixed)
    return new


def parameter_set_of(machine, data, kinds, parameters: str | None, notes: list):
    """The parameter set a calibration fits: ``parameters`` as given, else the one the data's
    source suggests (a firmware's saved data are fitted in the set that firmware fits them
    in); a set of lengths fitted from data that fix none falls back to its ``without_lengths``
    set; a set fitted from some kinds of data alone leaves the other files out (named in
    ``notes``).

    Parameters
    ----------
    machine : Machine
        The machine.
    data : object or list
        The data (objects or paths).
    kinds : list of MeasurementKind
        Their kinds, in order.
    parameters : str or None
        ``--parameters`` (None: not given).
    notes : list of str
        What the calibration notes; a file left out is appended.

    Returns
    -------
    tuple
        ``(machine, data, name, note)``: the machine with the set's fixed flags (as given
        when no set applies), the data kept, the set's name (None) and the note on the choice.

    Raises
    ------
    InputError
        When no data file holds the kinds the set is fitted from.
    """
    items = list(data) if isinstance(data, (list, tuple)) else [data]
    sets = getattr(machine, "PARAMETER_SETS", {})
    note = ""
    suggested = {getattr(d, "parameter_set", None) for d in items}
    if parameters is None and len(suggested) == 1 and None not in suggested \
            and next(iter(suggested)) in sets:
        parameters = next(iter(suggested))
        note = (f"the firmware's saved data: fitted in its own set (--parameters "
                f"{parameters}; --parameters full fits every tower quantity)")
    if parameters is None:
        return machine, data, None, note
    fallback = getattr(sets.get(parameters), "without_lengths", None)
    if fallback and not any(k.fixes_lengths for k in kinds):
        note = ((note + "; ") if note else "") + (
            f"{parameters} with heights alone is {fallback}: no measurement fixes a "
            "length (as the firmware does without distances)")
        parameters = fallback
    subset = sets.get(parameters)
    if getattr(subset, "kinds", None):
        out = [getattr(d, "source", str(d)) for d, k in zip(items, kinds, strict=True)
               if k.name not in subset.kinds]
        if len(out) == len(items):
            raise InputError(f"--parameters {parameters}: fitted from "
                             f"{' and '.join(subset.kinds)} data alone "
                             f"({subset.description.split(':')[0]}); "
                             f"{', '.join(map(str, out))} hold none")
        if out:
            items = [d for d, k in zip(items, kinds, strict=True) if k.name in subset.kinds]
            notes.append(f"{', '.join(map(str, out))}: left out: --parameters "
                         f"{parameters} is fitted from {' and '.join(subset.kinds)} data "
                         f"alone ({subset.description.split(':')[0]})")
            data = items[0] if len(items) == 1 else items
    return apply_parameter_set(machine, parameters), data, str(parameters), note
