"""Numpydoc checks of the public library API (``numpydoc.validate``).

The API walked here: every function and class in ``__all__`` of the subpackages in
``PACKAGES``, the public functions and classes defined in the modules in ``MODULES``, and the
public methods and properties of those classes that are defined in pkmcal (inherited numpy,
pydantic, dataclass or exception machinery is not ours to document). An object is checked once,
under the import path of the module and class that define it.

Enforced error codes (``ENFORCED``) - the ones that say whether the documentation is there and
agrees with the code, not how it is phrased:

* GL08 - no docstring at all.
* GL06, GL07 - a misspelt section title (``Return``, ``Parameter``) or sections out of order:
  numpydoc silently drops such a section, so the text would be lost to the rendered docs.
* SS01 - no one-line summary.
* PR01, PR02, PR03 - the documented parameters are exactly the signature's, in its order: a
  parameter renamed, added or removed without its docstring is the drift this test exists to
  catch.
* PR04, PR07, PR10 - every documented parameter has a type (shapes and units go there or in
  the description) and a description, and ``name : type`` is spelt so numpydoc can parse it.
* PR06 - ``int``/``bool``/``str``, not ``integer``/``boolean``/``string``.
* RT01, RT03 - a function or method that returns a value has a described Returns section.
  numpydoc applies RT01 only to functions that contain a ``return <value>``, so properties,
  ``__init__`` and functions returning None are exempt by construction; classmethods (which it
  skips) are checked the same way through their underlying function.
* YD01 - generators document what they yield.

Not enforced: style codes (SS02-SS06 capitalisation, final period, imperative mood, one-line
summary; PR08/PR09, RT04/RT05 the same for descriptions; GL01-GL03 blank lines; RT02 named
single returns, which the library uses on purpose to name the returned quantity) and the
sections this library does not promise (ES01 extended summary, SA01 See Also, EX01 Examples).

Dataclasses, NamedTuples and pydantic models: their fields are the class signature, and a field
documented in the class docstring's ``Attributes`` section counts as documented (the numpydoc
convention for records) - PR01/PR02/PR03 are recomputed against Parameters + Attributes for
them instead of asking for the same text twice. A ``typing.Protocol`` is never instantiated, so
its (inherited ``*args, **kwargs``) signature is not checked; its methods are. A method without
a docstring that overrides a documented pkmcal method with the same parameters inherits that
documentation (Sphinx's ``autodoc_inherit_docstrings``); the base method is checked itself.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect

import numpydoc.validate as validate_mod
from numpydoc.docscrape import NumpyDocString, get_doc_object

PACKAGES = [
    "pkmcal.kinematics", "pkmcal.machines", "pkmcal.instruments", "pkmcal.calibration",
    "pkmcal.identifiability", "pkmcal.analysis", "pkmcal.io", "pkmcal.planning",
    "pkmcal.compensation",
]
MODULES = ["pkmcal.report.html", "pkmcal.report.plots", "pkmcal.units", "pkmcal.errors"]

ENFORCED = {
    "GL06", "GL07", "GL08", "SS01", "PR01", "PR02", "PR03", "PR04", "PR06", "PR07", "PR10",
    "RT01", "RT03", "YD01",
}
SIGNATURE_CODES = {"PR01", "PR02", "PR03"}


def _ours(obj) -> bool:
    return getattr(obj, "__module__", "").startswith("pkmcal")


def _is_record(cls) -> bool:
    """Dataclass, NamedTuple or pydantic model: fields documented as Attributes."""
    return (dataclasses.is_dataclass(cls) or hasattr(cls, "_fields")
            or hasattr(cls, "model_fields"))


def _members(cls):
    """(path, object, defining class) of the public methods and properties of ``cls`` that
    are defined in pkmcal classes (``cls`` or its pkmcal bases)."""
    for klass in cls.__mro__:
        if not _ours(klass):
            continue
        for name, attr in vars(klass).items():
            if name.startswith("_"):
                continue
            if isinstance(attr, property | functools.cached_property | staticmethod
                          | classmethod) or inspect.isfunction(attr):
                yield f"{klass.__module__}.{klass.__qualname__}.{name}", attr, klass


def _api() -> tuple[dict[str, object], dict[str, type]]:
    """Import path -> object of everything checked, and path -> defining class of members."""
    roots = []
    for pkg in PACKAGES:
        mod = importlib.import_module(pkg)
        roots += [getattr(mod, name) for name in mod.__all__]
    for modname in MODULES:
        mod = importlib.import_module(modname)
        roots += [obj for name, obj in vars(mod).items()
                  if not name.startswith("_") and getattr(obj, "__module__", None) == modname
                  and (inspect.isfunction(obj) or inspect.isclass(obj))]
    api: dict[str, object] = {}
    owners: dict[str, type] = {}
    for obj in roots:
        if not (inspect.isfunction(obj) or inspect.isclass(obj)) or not _ours(obj):
            continue  # constants (METHODS, CRITERIA, ...) and re-exported foreign objects
        api[f"{obj.__module__}.{obj.__qualname__}"] = obj
        if inspect.isclass(obj):
            for path, attr, klass in _members(obj):
                api[path] = attr
                owners[path] = klass
    return api, owners


API, OWNERS = _api()


def _record_signature_errors(cls) -> list[tuple[str, str]]:
    doc = NumpyDocString(inspect.getdoc(cls) or "")
    documented = [n for sec in ("Parameters", "Attributes")
                  for p in doc[sec] for n in p.name.split(", ")]
    try:
        fields = list(inspect.signature(cls).parameters)
    except (TypeError, ValueError):
        return []
    errs = []
    missing = [f for f in fields if f not in documented]
    if missing:
        errs.append(("PR01", f"Parameters {missing} not documented"))
    params = [n for p in doc["Parameters"] for n in p.name.split(", ")]
    extra = [p for p in params if p not in fields]
    if extra:
        errs.append(("PR02", f"Unknown parameters {extra}"))
    order = [n for n in documented if n in fields]
    if not missing and order != fields:
        errs.append(("PR03", f"Wrong parameters order. Actual: {fields}. Documented: {order}"))
    return errs


def _inherited_doc_ok(path: str, obj) -> bool:
    """A method without a docstring that overrides a documented pkmcal method with the same
    parameters inherits its documentation (as Sphinx's ``autodoc_inherit_docstrings`` shows
    it); the base method is checked itself."""
    func = obj.__func__ if isinstance(obj, staticmethod | classmethod) else obj
    if not inspect.isfunction(func) or func.__doc__:
        return False
    owner, name = OWNERS.get(path), func.__name__
    if owner is None:
        return False
    for base in owner.__mro__[1:]:
        attr = vars(base).get(name)
        if attr is None or not _ours(base):
            continue
        base_func = attr.__func__ if isinstance(attr, staticmethod | classmethod) else attr
        return bool(getattr(base_func, "__doc__", None)) and (
            list(inspect.signature(base_func).parameters)
            == list(inspect.signature(func).parameters))
    return False


def _errors(path: str, obj) -> list[tuple[str, str]]:
    if _inherited_doc_ok(path, obj):
        return []
    result = validate_mod.validate(path)
    errs = list(result["errors"])
    if inspect.isclass(obj) and getattr(obj, "_is_protocol", False):
        # a typing.Protocol is never instantiated: its signature is Protocol's (*args, **kwargs)
        errs = [e for e in errs if e[0] not in SIGNATURE_CODES]
    elif inspect.isclass(obj) and _is_record(obj) and inspect.getdoc(obj):
        errs = [e for e in errs if e[0] not in SIGNATURE_CODES] + _record_signature_errors(obj)
    if isinstance(obj, classmethod):
        # numpydoc sees a bound method and skips its Returns checks; check the function
        inner = validate_mod.validate(get_doc_object(obj.__func__))
        errs += [e for e in inner["errors"] if e[0] in {"RT01", "YD01"}]
    return [e for e in errs if e[0] in ENFORCED]


def test_api_is_not_empty():
    assert len(API) > 100


def test_public_docstrings():
    offenders = []
    for path, obj in sorted(API.items()):
        for code, message in _errors(path, obj):
            offenders.append(f"{path}: {code} {message}")
    assert not offenders, f"{len(offenders)} docstring errors:\n" + "\n".join(offenders)
