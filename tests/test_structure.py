"""The package's structure holds (issue 25): no import cycle, and no new switch on an
instrument's or a machine's name outside the modules that own it.

The counts come from :mod:`structure_audit` (AST and the import graph, imports inside
functions included). There is no switch left (742829e had 100); the ceilings below are
empty, so any new one fails: ask the instrument or the machine instead.
"""

from __future__ import annotations

from functools import cache

import structure_audit as audit

#: switches on instrument/machine names still standing, per module: none
SWITCH_CEILINGS: dict[str, int] = {}
#: ``pose_dof`` comparisons still standing, per module (a machine's ``pose_space`` says which
#: pose coordinates move; target: none outside machines/base.py)
POSE_DOF_CEILINGS = {"machines/base.py": 1}


@cache
def _audit() -> dict:
    """The audit (~2.5 s), made by the first test that reads it: at import it ran while every
    pytest-xdist worker collected the tests, whichever worker ran them."""
    return audit.audit()


def test_no_import_cycle_between_modules_or_packages():
    assert _audit()["module_cycles"] == [], _audit()["module_cycles"]
    assert _audit()["package_cycles"] == [], _audit()["package_cycles"]


def test_switches_on_names_only_fall():
    over = {rel: [ln for ln, _, _ in found] for rel, found in _audit()["switches"].items()
            if len(found) > SWITCH_CEILINGS.get(rel, 0)}
    assert not over, ("new switches on an instrument's or machine's name outside its module "
                      f"(ask the registry or the machine instead): {over}")


def test_translation_tests_only_fall():
    over = {rel: lines for rel, lines in _audit()["translation_tests"].items()
            if len(lines) > POSE_DOF_CEILINGS.get(rel, 0)}
    assert not over, f"new pose_dof tests (use machine.pose_space / machine.rotates): {over}"


def test_audit_sees_a_switch_and_a_cycle(tmp_path):
    """The audit is not blind: a planted switch and a planted cycle are found."""
    module = tmp_path / "m.py"
    module.write_text("def f(kind, data):\n"
                      "    if kind == 'tracker':\n        return 1\n"
                      "    table = {'probe': 1, 'distance': 2}\n"
                      "    return isinstance(data, TrackerData) or table\n")
    found = audit.switches(module, "cli/x.py")
    assert sorted(what for _, what, _ in found) == ["comparison", "isinstance",
                                                    "name-keyed table"]
    assert audit.switches(module, "instruments/tracker/__init__.py")[0][2] == ("distance", "probe")
    assert audit.cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def _code_mentions(words: set) -> dict:
    """Modules whose code (not docstrings or comments) names any of ``words``: string
    constants, identifiers and attributes."""
    import ast

    out = {}
    for path in sorted(audit.ROOT.rglob("*.py")):
        tree = ast.parse(path.read_text())
        docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                      if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef,
                                           ast.AsyncFunctionDef))
                      and node.body and isinstance(node.body[0], ast.Expr)
                      and isinstance(node.body[0].value, ast.Constant)}
        hits = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                    and id(node) not in docstrings:
                hits |= {w for w in words if w in node.value}
            elif isinstance(node, ast.Name) and node.id in words:
                hits.add(node.id)
            elif isinstance(node, ast.Attribute) and node.attr in words:
                hits.add(node.attr)
            elif isinstance(node, ast.alias) and any(w in node.name for w in words):
                hits.add(node.name)
        if hits:
            out[str(path.relative_to(audit.ROOT))] = hits
    return out


def test_the_planar_robot_is_one_module_and_one_registry_line():
    """The proof of issue 25: the 3-RPR machine is named in its module and in the machine
    registry's list, nowhere else in the package's code."""
    mentions = _code_mentions({"planar_3rpr", "Planar3RPR"})
    assert set(mentions) == {"machines/planar_3rpr.py", "machines/registry.py"}, mentions


def test_the_two_point_distances_are_one_module_and_one_registry_line():
    """The second proof of issue 25: the two-point distance instrument is named in its module,
    in the instrument registry's list ("pairs") and in Klipper's format, whose saved
    DELTA_ANALYZE distances are its data; nowhere else in the package's code."""
    mentions = _code_mentions({"pair-distances", "PairDistance", "pair_data", "PairProblem",
                               "PairDistanceModel", "instruments.pairs"})
    assert set(mentions) <= {"instruments/pairs.py", "io/klipper_data.py"}, mentions
    from pkmcal.instruments.registry import INSTRUMENT_MODULES

    assert "pairs" in INSTRUMENT_MODULES


#: what calibration/run.py still names of the tracker, ballbar, full-pose and constraint-link
#: instruments (issue 38): nothing since their parts of a fit of several files moved into their
#: modules (Instrument.joint_part); this set only shrinks
RUN_NAMES_LEFT: set = set()
#: calibration/run.py's line budget: 2,842 lines before the four older flows moved into their
#: instruments (2,042 after; 1,962 after the probe's; 1,826 after the joint parts); the issue's
#: target, 600, since the joint flow, the kinds, the acceptance and the result have modules of
#: their own (calibration/joint.py, kinds.py, acceptance.py, result.py, ...)
RUN_LINE_BUDGET = 600


def _instrument_names_in(path) -> set:
    """Identifiers (names, attributes, definitions, imports) of a module's code naming the
    tracker, ballbar, full-pose or constraint-link instrument, and string constants that are
    one of their names (docstrings and comments aside)."""
    import ast

    from pkmcal.instruments.registry import INSTRUMENTS

    # the older instruments' words, and every instrument's name and aliases
    words = ("tracker", "distance", "ballbar", "constraint", "full_pose", "fullpose", "pose",
             "probe", "bed", "mocap", "klipper", "marlin",
             *(w.replace("-", "_") for inst in INSTRUMENTS.values()
               for w in (inst.name, *inst.aliases)))
    names = {n for n, owner in audit.INSTRUMENT_NAMES.items()
             if owner in ("tracker", "distance", "pose", "constraint-link")}
    tree = ast.parse(path.read_text())
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr)
                  and isinstance(node.body[0].value, ast.Constant)}
    package = "pkmcal.calibration"
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            if id(node) not in docstrings and node.value in names:
                found.add(node.value)
            elif id(node) not in docstrings:
                found |= {w for w in words if w in node.value.lower()}
            continue
        texts = ([node.id] if isinstance(node, ast.Name) else
                 [node.attr] if isinstance(node, ast.Attribute) else
                 [node.name] if isinstance(node, (ast.FunctionDef, ast.ClassDef, ast.alias))
                 else [])
        if isinstance(node, ast.ImportFrom) and node.module:
            base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
            texts = [f"{base}.{node.module}" if node.level else node.module]
        found |= {t for t in texts if any(w in t.lower() for w in words)}
    return found


def test_run_names_no_flow_of_the_older_instruments_and_keeps_its_budget():
    """Issue 38: the tracker, full-pose, ballbar and constraint-link flows live in their
    instruments' modules; run.py dispatches them through the registry, naming none (but the
    joint parts still there), within its line budget."""
    run = audit.ROOT / "calibration" / "run.py"
    found = _instrument_names_in(run)
    assert found <= RUN_NAMES_LEFT, sorted(found - RUN_NAMES_LEFT)
    for flow in ("_calibrate_tracker", "_calibrate_full_pose", "_calibrate_distances",
                 "_calibrate_constraint_link", "_calibrate_probe", "_check_heights",
                 "_joint_tracker", "_joint_distances", "_joint_probe", "JOINT_PARTS",
                 "register_joint_part"):
        assert flow not in run.read_text(), flow
    lines = run.read_text().count("\n")
    assert lines <= RUN_LINE_BUDGET, lines


def test_the_names_audit_sees_a_flow(tmp_path):
    """Not blind: a module importing an instrument's module, defining a tracker flow and
    comparing with "pose" is found."""
    module = tmp_path / "m.py"
    module.write_text("from ..instruments.constraint_link import link_noise_arg\n"
                      "def _calibrate_tracker(kind):\n    return kind == 'pose'\n")
    assert _instrument_names_in(module) == {"pkmcal.instruments.constraint_link",
                                            "_calibrate_tracker", "pose"}


#: the command line's line budget (issue 38): the typer declarations, main()'s glue and the
#: console; each command's work is a function of pkmcal.workflows (4,108 lines before)
CLI_LINE_BUDGET = 1500


def test_the_command_line_is_a_thin_layer_within_its_budget():
    """Issue 38: the CLI parses, calls one library function per command and prints: its
    modules together stay within the budget, and no CLI module defines a ``run_*`` body of a
    command's work (those are :mod:`pkmcal.workflows`' functions)."""
    cli = sorted((audit.ROOT / "cli").glob("*.py"))
    lines = sum(p.read_text().count("\n") for p in cli)
    assert lines <= CLI_LINE_BUDGET, lines
    import ast

    bodies = [f"{p.name}:{node.name}" for p in cli for node in ast.walk(ast.parse(p.read_text()))
              if isinstance(node, ast.FunctionDef) and node.name.startswith("run_")]
    assert bodies == [], bodies
