"""Structure audit of the package, as an outside reviewer measures it (AST and import graph).

Counts, over ``src/pkmcal``:

- *switches* on an instrument's or a machine's name or class outside the module(s) that own
  it: a comparison of a name-bearing expression (its text names a ``kind``, ``name``,
  ``scenario``, ``instrument``, ``measurement``, ``type`` or ``machine``) with the name
  (``kind == "probe"``, ``scenario in ("tracker", "points")``), a table keyed by two or more
  names (``{"tracker": ..., "probe": ...}``), ``isinstance`` with the class, a ``match`` case
  on the name. A Klipper ``kinematics: delta`` or a design criterion ``"pose"`` is no switch;
- *translation tests*: comparisons of ``pose_dof`` (``pose_dof == 3`` standing for "the
  platform only translates"; a machine's ``pose_space`` says which coordinates move);
- *import cycles*: strongly connected components of the module import graph (imports inside
  functions included: hiding an import in a function does not remove the dependence);
- lines per subpackage and the longest functions.

Run ``python tests/structure_audit.py`` for the table; ``tests/test_structure.py`` holds the
counts to their ceilings.
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "src" / "pkmcal"

#: machine names (``Machine.kind``, machine-file ``machine:``) and classes -> owning modules
MACHINES = {
    "delta": ("machines/delta.py",),
    "linear_delta": ("machines/linear_delta.py",),
    "hexaslide": ("machines/hexaslide.py",),
    "stewart": ("machines/stewart.py",),
    "planar_3rpr": ("machines/planar_3rpr.py",),
}
MACHINE_CLASSES = {"Delta": "delta", "LinearDelta": "linear_delta", "HexaSlide": "hexaslide",
                   "Stewart": "stewart", "Planar3RPR": "planar_3rpr"}

#: instrument names, aliases and data kinds -> the instrument
INSTRUMENT_NAMES = {
    "constraint-link": "constraint-link", "constraint_link": "constraint-link",
    "tracker": "tracker", "points": "tracker",
    "pose": "pose", "poses": "pose", "full-pose": "pose", "full_pose": "pose",
    "distance": "distance", "distances": "distance", "ballbar": "distance",
    "probe": "probe", "probe-heights": "probe", "bed-probe": "probe",
    "pair-distances": "pair-distances", "caliper": "pair-distances",
    "two-point-distances": "pair-distances",
}
INSTRUMENT_CLASSES = {
    "ConstraintLinkData": "constraint-link", "ConstraintLinkML": "constraint-link",
    "TrackerData": "tracker", "TrackerProblem": "tracker", "PointsModel": "tracker",
    "TrackerNoise": "tracker",
    "FullPoseData": "pose", "FullPoseML": "pose", "FullPoseNoise": "pose",
    "DistancesModel": "distance", "ProbeModel": "probe", "ProbeProblem": "probe",
    "PairDistanceModel": "pair-distances", "PairProblem": "pair-distances",
}
#: modules owning each instrument (its definition, its data, model and calibration)
INSTRUMENT_OWNERS = {
    "constraint-link": tuple(f"instruments/constraint_link/{m}.py" for m in (
        "__init__", "data", "start", "problems", "section", "methods")),
    "tracker": tuple(f"instruments/tracker/{m}.py" for m in (
        "__init__", "noise", "setup", "data", "section", "fit", "distances")),
    "pose": tuple(f"instruments/pose/{m}.py" for m in (
        "__init__", "data", "problems", "errors", "section")),
    "distance": ("instruments/distance.py",),
    "probe": ("instruments/probe.py", "instruments/bed.py"),
    "pair-distances": ("instruments/pairs.py",),
}


def _owners(subject: str) -> tuple:
    if subject in MACHINES:
        return MACHINES[subject]
    return INSTRUMENT_OWNERS.get(subject, ())


def _subject_of_constant(node) -> str | None:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        v = node.value
        if v in INSTRUMENT_NAMES:
            return INSTRUMENT_NAMES[v]
        if v in MACHINES:
            return v
    return None


def _subjects(node) -> set:
    """Names/classes of instruments or machines a comparator stands for."""
    out = set()
    s = _subject_of_constant(node)
    if s:
        out.add(s)
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        for e in node.elts:
            out |= _subjects(e)
    return out


def _class_subject(node) -> set:
    out = set()
    if isinstance(node, ast.Name):
        name = node.id
    elif isinstance(node, ast.Attribute):
        name = node.attr
    elif isinstance(node, ast.Tuple):
        for e in node.elts:
            out |= _class_subject(e)
        return out
    else:
        return out
    if name in MACHINE_CLASSES:
        out.add(MACHINE_CLASSES[name])
    if name in INSTRUMENT_CLASSES:
        out.add(INSTRUMENT_CLASSES[name])
    return out


#: words in an expression that make it name-bearing (what a switch compares)
NAME_WORDS = ("kind", "name", "scenario", "instrument", "measurement", "type", "machine")


def _name_bearing(node) -> bool:
    text = ast.unparse(node).lower()
    return any(w in text for w in NAME_WORDS)


def switches(path: Path, rel: str) -> list:
    """``[(line, what, subjects)]``: switches of a module outside the subjects' owners."""
    tree = ast.parse(path.read_text(), str(path))
    found = []
    for node in ast.walk(tree):
        subjects, what = set(), ""
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            names = [c for c in sides if _subjects(c)]
            others = [c for c in sides if not _subjects(c)]
            if names and any(_name_bearing(c) for c in others):
                for c in names:
                    subjects |= _subjects(c)
            what = "comparison"
        elif isinstance(node, ast.Dict):
            keys = [k for k in node.keys if k is not None]
            hit = set()
            for k in keys:
                hit |= _subjects(k)
            if sum(bool(_subjects(k)) for k in keys) >= 2:
                subjects, what = hit, "name-keyed table"
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ("isinstance", "issubclass") and len(node.args) == 2):
            subjects, what = _class_subject(node.args[1]), "isinstance"
        elif isinstance(node, ast.match_case):
            for sub in ast.walk(node.pattern):
                if isinstance(sub, ast.MatchValue):
                    subjects |= _subjects(sub.value)
            what = "match case"
        subjects = {s for s in subjects if rel not in _owners(s)}
        if subjects:
            found.append((node.lineno if hasattr(node, "lineno") else node.pattern.lineno,
                          what, tuple(sorted(subjects))))
    return found


def translation_tests(path: Path) -> list:
    """Lines comparing ``pose_dof`` (a machine's ``pose_space`` says what moves)."""
    tree = ast.parse(path.read_text(), str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            for c in [node.left, *node.comparators]:
                if isinstance(c, ast.Attribute) and c.attr == "pose_dof":
                    out.append(node.lineno)
                    break
    return out


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def import_graph() -> dict:
    """Module -> set of pkmcal modules it imports (anywhere in the module)."""
    modules = {_module_name(p): p for p in ROOT.rglob("*.py")}
    graph = defaultdict(set)
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        for node in ast.walk(tree):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [mod]
                for a in node.names:          # from .x import y: y may be a module
                    if f"{mod}.{a.name}" in modules:
                        targets.append(f"{mod}.{a.name}")
                if node.module is None and len(targets) == len(node.names) + 1:
                    # from . import x, y of modules: those modules (as ``from .x import z``
                    # depends on x alone), not the package's __init__
                    targets = targets[1:]
            for t in targets:
                if t.startswith("pkmcal"):
                    while t and t not in modules:
                        t = t.rsplit(".", 1)[0] if "." in t else ""
                    if t and t != name:
                        graph[name].add(t)
        graph.setdefault(name, set())
    return graph


def package_graph(graph: dict) -> dict:
    """Subpackage -> subpackages it imports (``pkmcal.x`` for ``pkmcal.x.y``)."""
    def top(m):
        parts = m.split(".")
        return ".".join(parts[:2])
    out = defaultdict(set)
    for m, deps in graph.items():
        for d in deps:
            if top(d) != top(m):
                out[top(m)].add(top(d))
        out.setdefault(top(m), set())
    return out


def cycles(graph: dict) -> list:
    """Strongly connected components of more than one node (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def audit() -> dict:
    """Every count of the module docstring."""
    sw, tt, lines, funcs = {}, {}, defaultdict(int), []
    for path in sorted(ROOT.rglob("*.py")):
        rel = str(path.relative_to(ROOT))
        found = switches(path, rel)
        if found:
            sw[rel] = found
        t = translation_tests(path)
        if t:
            tt[rel] = t
        text = path.read_text()
        pkg = rel.split("/")[0] if "/" in rel else "(top)"
        lines[pkg] += text.count("\n")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                funcs.append((node.end_lineno - node.lineno + 1, f"{rel}:{node.name}"))
    graph = import_graph()
    return {"switches": sw, "translation_tests": tt, "lines": dict(lines),
            "longest": sorted(funcs, reverse=True)[:10],
            "module_cycles": cycles(graph), "package_cycles": cycles(package_graph(graph))}


def main() -> None:
    a = audit()
    total = sum(len(v) for v in a["switches"].values())
    print(f"switches outside owners: {total}")
    for rel, found in sorted(a["switches"].items(), key=lambda kv: -len(kv[1])):
        print(f"  {len(found):3d} {rel}: " + ", ".join(f"{ln}" for ln, _, _ in found))
    print(f"pose_dof tests: {sum(len(v) for v in a['translation_tests'].values())}")
    for rel, ln in a["translation_tests"].items():
        print(f"  {len(ln):3d} {rel}")
    print(f"module cycles: {len(a['module_cycles'])}")
    for c in a["module_cycles"]:
        print("   ", " <-> ".join(c))
    print(f"package cycles: {len(a['package_cycles'])}")
    for c in a["package_cycles"]:
        print("   ", " <-> ".join(c))
    print("lines per package:")
    for pkg, n in sorted(a["lines"].items(), key=lambda kv: -kv[1]):
        print(f"  {n:6d} {pkg}")
    print("longest functions:")
    for n, f in a["longest"]:
        print(f"  {n:5d} {f}")


if __name__ == "__main__":
    main()
