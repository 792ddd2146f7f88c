"""Machine files that are hostile or absurd are refused up front (issue 11, SPEC 6 "Bad input").

- YAML bombs: nested aliases ("billion laughs"), recursive aliases, thousands of nesting levels
  and oversized files are refused up front with bounded work and memory, before anything is
  expanded (an oversized file before a byte of it is read), naming the file and the key; never
  a RecursionError. Work is counted in Python function calls, not timed: these tests hold on
  any machine under any load, and a bomb that gets through fails them instead of hanging.
- Finite but absurd numbers (1e308 lengths, angles, gains) are refused against the machine's own
  size, naming the key, with no numpy warning.
- Degenerate geometry (identical chains or legs, legs at the same angle, arms that reach
  nowhere, a Jacobian singular at home) is refused naming the keys; legit non-default
  geometries (120-degree Deltas, three-rail Hexa Slides) still load.
- Through the command line: exit code 2, one line on stderr, no traceback, no output file.
"""

from __future__ import annotations

import builtins
import contextlib
import re
import sys
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, run
from pkmcal.errors import InputError
from pkmcal.io import load_machine, parse_machine, parse_machine_file
from pkmcal.limits import MAX_MACHINE_FILE_BYTES

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
HEXA = (EXAMPLES / "hexaslide_default.yaml").read_text()
DELTA = (EXAMPLES / "delta_default.yaml").read_text()
CUBIC = (EXAMPLES / "cubic_6upu.yaml").read_text()
HEAD = "pkmcal: 1\nmachine: hexaslide\nunits: {length: mm, angle: deg}\n"


def refused(text: str, source: str = "m.yaml") -> str:
    """The message of the InputError that parsing ``text`` raises, with no warning on the way."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError) as exc:
            parse_machine(text, source)
    return str(exc.value)


def loads(text: str):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return parse_machine(text, "m.yaml")


#: Python function calls within which a hostile machine file must be refused: a count of the
#: work, not a clock. Reading a real machine file takes 12 000-18 000 (once the machine formats
#: are set up), the costliest refusal here about 33 000 (5000 nested flow sequences, in PyYAML's
#: scanner); without the alias guard, loading a bomb of 10^6 values takes 2.3 million and a
#: billion laughs never ends.
REFUSAL_CALLS = 200_000
#: the same through the command line, its start-up included: about 250 000 in a fresh process,
#: 50 000-70 000 once the modules are imported
CLI_CALLS = 1_000_000


class _OverBudget(BaseException):
    """Raised inside the code under test when it exceeds its budget of calls (a BaseException:
    no ``except Exception`` of the code can swallow it)."""


@contextlib.contextmanager
def call_budget(limit: int):
    """Fail as soon as the code inside makes more than ``limit`` Python function calls
    (``sys.setprofile``'s "call" events): a count of the work done, the same on any machine
    under any load, which stops a parser that expands a bomb instead of letting it hang."""
    calls = 0

    def count(frame, event, arg):
        nonlocal calls
        if event == "call":
            calls += 1
            if calls > limit:
                sys.setprofile(None)
                raise _OverBudget

    previous = sys.getprofile()
    sys.setprofile(count)
    try:
        yield
    except _OverBudget:
        pytest.fail(f"not refused within {limit} Python function calls: the input was "
                    "expanded or walked instead of refused up front", pytrace=False)
    finally:
        sys.setprofile(previous)


def refused_up_front(text: str, megabytes: float = 50.0) -> str:
    """Refused within :data:`REFUSAL_CALLS` function calls, using at most ``megabytes`` of
    Python memory (measured in a second run, which tracing slows several times)."""
    with call_budget(REFUSAL_CALLS):
        message = refused(text)
    tracemalloc.start()
    try:
        refused(text)
        peak = tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()
    assert peak < megabytes, (peak, message)
    return message


def billion_laughs(levels: int = 12) -> str:
    lines = [HEAD.rstrip("\n"), "a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


# -- YAML bombs ---------------------------------------------------------------------------------

def test_alias_bomb_is_refused_up_front_with_bounded_work_and_memory():
    message = refused_up_front(billion_laughs())
    assert message.startswith("m.yaml: a"), message
    assert "aliases" in message and "(line " in message, message


def test_alias_bomb_inside_a_known_key_names_that_key():
    text = HEAD + "x: &x [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
        f"x{i}: &x{i} [{', '.join(['*x' + (str(i - 1) if i > 1 else '')] * 10)}]\n"
        for i in range(1, 6)) + "chains: [*x5]\n"
    message = refused_up_front(text)
    assert re.match(r"m.yaml: x\d(\[\d\])?: .*aliases", message), message


def test_recursive_alias_is_refused():
    message = refused_up_front(HEAD + "chains: &c [1, *c]\n")
    assert message.startswith("m.yaml: chains[1]: ") and "recursive alias" in message, message


@pytest.mark.parametrize("nest", [
    lambda n: "[" * n + "]" * n,                      # flow sequences
    lambda n: "{a: " * n + "1" + "}" * n,             # flow mappings
    lambda n: "{? " * n + "1" + "}" * n,              # mappings as keys of mappings
    lambda n: "".join("\n" + "  " * (k + 1) + "a:" for k in range(n)) + " 1",  # block
], ids=["sequences", "mappings", "keys", "block"])
def test_deep_nesting_is_refused_up_front_without_recursion_error(nest):
    message = refused_up_front(HEAD + "chains: " + nest(5000) + "\n")
    assert message.startswith("m.yaml: chains") and "nested more than" in message, message
    assert "Recursion" not in message


def test_anchors_and_aliases_of_reasonable_size_still_load():
    zero = "{da: [0.0, 0.0, 0.0], dtheta: 0.0, dl1: 0.0, dl2: 0.0, db: [0.0, 0.0, 0.0]}"
    text = re.sub(r"legs:\n(  - .*\n){3}",
                  f"legs:\n  - &zero {zero}\n  - *zero\n  - *zero\n", DELTA)
    assert "*zero" in text
    m = loads(text)
    assert np.all(m.u == 0)


def _reads_of(path: Path, monkeypatch) -> list[str]:
    """The read calls (``read``, ``readinto``, ...) made on file objects that ``open`` gives
    for ``path`` while ``monkeypatch`` is in effect; appended to the list returned."""
    reads: list[str] = []
    real_open = builtins.open

    class Watched:
        def __init__(self, f):
            self._f = f

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return self._f.__exit__(*exc)

        def __getattr__(self, name):
            attr = getattr(self._f, name)
            if not name.startswith("read"):
                return attr

            def read(*args, **kwargs):
                reads.append(name)
                return attr(*args, **kwargs)
            return read

    def watched_open(file, *args, **kwargs):
        f = real_open(file, *args, **kwargs)
        if isinstance(file, (str, Path)) and Path(file) == path:
            return Watched(f)
        return f

    monkeypatch.setattr(builtins, "open", watched_open)
    return reads


def test_oversized_machine_file_is_refused_before_it_is_read(tmp_path, monkeypatch):
    huge = tmp_path / "huge.yaml"
    with open(huge, "wb") as f:                        # sparse: 2 GB, no disk used
        f.truncate(2 * 1024**3)
    with monkeypatch.context() as patch:
        reads = _reads_of(huge, patch)
        with pytest.raises(InputError) as exc:
            load_machine(huge)
    assert reads == [], reads                          # not a byte read: its size refused it
    message = str(exc.value)
    assert message.startswith(f"{huge}: the machine file is 2147483648 bytes"), message
    assert f"at most {MAX_MACHINE_FILE_BYTES} bytes" in message, message


def test_machine_file_just_below_the_size_limit_reads(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(HEXA + "# " + "x" * (MAX_MACHINE_FILE_BYTES - len(HEXA) - 10) + "\n")
    assert path.stat().st_size <= MAX_MACHINE_FILE_BYTES
    assert load_machine(path).kind == "hexaslide"


# -- absurd values ------------------------------------------------------------------------------

def _sub(text: str, old: str, new: str, count: int = 1) -> str:
    assert old in text, old
    return text.replace(old, new, count)


def _chain(text: str, k: int, field: str, value: str) -> str:
    """Chain ``k`` of a Hexa Slide file with ``field`` set to ``value``."""
    lines = text.splitlines()
    idx = [i for i, line in enumerate(lines) if line.startswith("  - {a0")][k]
    pattern = {"l": r"l: [^}]*", "alpha": r"alpha: [^,]*", "beta": r"beta: [^,]*",
               "a0": r"a0: \[[^]]*\]", "b": r"b: \[[^]]*\]"}[field]
    lines[idx] = re.sub(pattern, f"{field}: {value}", lines[idx], count=1)
    return "\n".join(lines) + "\n"


def _leg(text: str, k: int, field: str, value: str) -> str:
    """Leg ``k`` of a Stewart or Delta file with ``field`` set to ``value``."""
    lines = text.splitlines()
    idx = [i for i, line in enumerate(lines) if line.startswith("  - {")][k]
    if field in ("base", "platform", "da", "db"):
        lines[idx] = re.sub(rf"\b{field}: \[[^]]*\]", f"{field}: {value}", lines[idx], count=1)
    else:
        lines[idx] = re.sub(rf"\b{field}: [^,}}]*", f"{field}: {value}", lines[idx], count=1)
    return "\n".join(lines) + "\n"


ABSURD = [
    ("hexaslide", lambda: _chain(HEXA, 2, "l", "1e308"), "chains[2].l"),
    ("hexaslide", lambda: _chain(HEXA, 0, "a0", "[1e308, 0, -400]"), "chains[0].a0[0]"),
    ("hexaslide", lambda: _chain(HEXA, 5, "b", "[0, 0, -1.5e308]"), "chains[5].b[2]"),
    ("hexaslide", lambda: _chain(HEXA, 1, "alpha", "1e308"), "chains[1].alpha"),
    ("hexaslide", lambda: _sub(HEXA, "{length: 300.0}", "{length: 1e308}"),
     "constraint_link.length"),
    ("hexaslide", lambda: _sub(HEXA, "home: [0.0, 0.0, 300.0", "home: [0.0, 0.0, 1e308"),
     "home[2]"),
    ("hexaslide", lambda: HEXA.replace("l: 450.0", "l: 1e308"), "chains[0].l"),  # 1000 km
    ("delta", lambda: _sub(DELTA, "forearm: 800.0", "forearm: 1e308"), "forearm"),
    ("delta", lambda: _sub(DELTA, "upper_arm: 300.0", "upper_arm: 1e308"), "upper_arm"),
    ("delta", lambda: _sub(DELTA, "base_radius: 200.0", "base_radius: 1e308"), "base_radius"),
    ("delta", lambda: _sub(DELTA, "smr_offset: 30.0", "smr_offset: -1e308"), "smr_offset"),
    ("delta", lambda: _sub(DELTA, "[90.0, 180.0, -90.0]", "[90.0, 1e308, -90.0]"),
     "leg_angles[1]"),
    ("delta", lambda: _leg(DELTA, 1, "dl2", "1e308"), "legs[1].dl2"),
    ("delta", lambda: _leg(DELTA, 2, "dtheta", "1e300"), "legs[2].dtheta"),
    ("delta", lambda: DELTA + "tracker: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "
                              "translation: [0, 1e308, 0]}\n", "tracker.translation[1]"),
    ("delta", lambda: _sub(DELTA, "home: [0.0, 0.0, -750.0]", "home: [0.0, 0.0, -1e308]"),
     "home[2]"),
    ("stewart", lambda: _leg(CUBIC, 3, "l0", "1e308"), "legs[3].l0"),
    ("stewart", lambda: _leg(CUBIC, 0, "gain", "1e308"), "legs[0].gain"),
    ("stewart", lambda: _leg(CUBIC, 4, "gain", "1e-300"), "legs[4].gain"),
    ("stewart", lambda: _leg(CUBIC, 2, "base", "[0, 0, 1e308]"), "legs[2].base[2]"),
    ("stewart", lambda: _leg(CUBIC, 5, "platform", "[1e308, 0, 0]"), "legs[5].platform[0]"),
    ("stewart", lambda: _sub(CUBIC, "home: [0.0, 0.0, 410.0, 0.0, 0.0, 0.0]",
                             "home: [0.0, 0.0, 410.0, 0.0, 1e308, 0.0]"), "home[4]"),
    ("stewart", lambda: CUBIC + "constraint_link: {length: 1e300}\n", "constraint_link.length"),
]


@pytest.mark.parametrize("kind, make, key", ABSURD,
                         ids=[f"{k}-{key}-{i}" for i, (k, _, key) in enumerate(ABSURD)])
def test_absurd_values_are_refused_naming_the_key(kind, make, key):
    text = make()
    assert f"machine: {kind}" in text
    message = refused(text)
    assert message.startswith(f"m.yaml: {key}: "), message
    assert "not a plausible" in message and "(line " in message, message


def test_large_but_sane_values_still_load():
    """A tracker metres away from a small Delta, a long-legged platform: not absurd."""
    text = DELTA + ("tracker: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "
                    "translation: [5000.0, -3000.0, 1500.0]}\n")
    assert loads(text).kind == "delta"
    _, setups = parse_machine_file(text, "m.yaml")
    assert np.allclose(setups["tracker"].base_from_tracker[1], [5.0, -3.0, 1.5])
    assert loads(_chain(HEXA, 0, "alpha", "520.0")).kind == "hexaslide"   # 520 = 160 deg


# -- degenerate geometry --------------------------------------------------------------------------

def _copy_line(text: str, src: int, dst: int) -> str:
    lines = text.splitlines()
    idx = [i for i, line in enumerate(lines) if line.startswith("  - {")]
    lines[idx[dst]] = lines[idx[src]]
    return "\n".join(lines) + "\n"


def _vertical_hexaslide() -> str:
    """Six vertical rails with the links straight up them at home: all six link directions
    are parallel, the platform can slide sideways and turn (Jacobian rank 3)."""
    chains = []
    for k in range(6):
        g = np.radians(60 * k)
        x, y = 200 * np.cos(g), 200 * np.sin(g)
        chains.append(f"  - {{a0: [{float(x)!r}, {float(y)!r}, -400.0], alpha: 0.0, beta: 90.0, "
                      f"b: [{float(x)!r}, {float(y)!r}, 0.0], l: 450.0}}")
    return HEAD + "chains:\n" + "\n".join(chains) + "\nhome: [0, 0, 300, 0, 0, 0]\n"


DEGENERATE = [
    ("hexaslide", lambda: _copy_line(HEXA, 0, 3), "chains[3]", "the same chain as chains[0]"),
    ("hexaslide", lambda: re.sub(r"b: \[[^]]*\]", "b: [10.0, 20.0, 0.0]", HEXA), "chains",
     "all six platform joints b are at one point"),
    ("hexaslide", _vertical_hexaslide, "home", "the six chains do not hold the platform at home"),
    ("hexaslide", lambda: _chain(HEXA, 4, "l", "45.0"), "home",
     "cannot be reached by chain(s) 5"),
    ("delta", lambda: _sub(DELTA, "[90.0, 180.0, -90.0]", "[90.0, 180.0, 90.0]"),
     "leg_angles[2]", "legs 1 and 3 stand at the same angle"),
    ("delta", lambda: _sub(DELTA, "[90.0, 180.0, -90.0]", "[90.0, 90.00001, -90.0]"),
     "leg_angles[1]", "legs 1 and 2 stand at the same angle"),
    ("delta", lambda: _sub(DELTA, "[90.0, 180.0, -90.0]", "[-90.0, 180.0, 270.0]"),
     "leg_angles[2]", "legs 1 and 3 stand at the same angle"),
    ("delta", lambda: _leg(DELTA, 2, "dl2", "-800.0"), "legs[2].dl2",
     "the forearm of leg 3 would be 0 mm long"),
    ("delta", lambda: _sub(_sub(DELTA, "base_radius: 200.0", "base_radius: 1500.0"),
                           "forearm: 800.0", "forearm: 700.0"), "forearm",
     "together are shorter than |base_radius - platform_radius| (1450 mm)"),
    ("stewart", lambda: _copy_line(CUBIC, 1, 4), "legs[4]", "the same leg as legs[1]"),
]


@pytest.mark.parametrize("kind, make, key, words", DEGENERATE,
                         ids=[f"{k}-{key}-{i}" for i, (k, _, key, _) in enumerate(DEGENERATE)])
def test_degenerate_geometry_is_refused_naming_the_keys(kind, make, key, words):
    text = make()
    assert f"machine: {kind}" in text
    message = refused(text)
    assert message.startswith(f"m.yaml: {key}: "), message
    assert words in message and "(line " in message, message


def test_legit_non_default_geometries_still_load():
    for angles in ("[90.0, 210.0, 330.0]", "[0.0, 120.0, 240.0]", "[30.0, 150.0, -90.0]",
                   "[0.0, 100.0, 200.0]"):
        m = loads(_sub(DELTA, "[90.0, 180.0, -90.0]", angles))
        assert np.all(np.isfinite(m.ik(m.home[0])))
    # a platform wider than the base, arms long enough
    assert loads(_sub(DELTA, "platform_radius: 50.0", "platform_radius: 400.0")).b == 0.4
    # three rails carrying two sliders each, to different platform joints
    lines = HEXA.splitlines()
    ch = [i for i, line in enumerate(lines) if line.startswith("  - {a0")]
    rail = r"a0: \[[^]]*\], alpha: [^,]*, beta: [^,]*,"
    for k in range(3):
        lines[ch[2 * k + 1]] = re.sub(rail, re.search(rail, lines[ch[2 * k]]).group(0),
                                      lines[ch[2 * k + 1]])
    three_rails = loads("\n".join(lines) + "\n")
    b, a0, *_ = three_rails.chains()
    assert np.allclose(a0[0], a0[1]) and not np.allclose(b[0], b[1])
    # two sliders on one rail to the same joint with different links: not degenerate
    same_joint = _copy_line(HEXA, 0, 1)
    same_joint = _chain(same_joint, 1, "l", "500.0")
    assert loads(same_joint).kind == "hexaslide"
    # other rail elevations
    assert loads(HEXA.replace("beta: 70.0", "beta: 60.0")).kind == "hexaslide"
    # six-leg platforms
    assert loads(CUBIC).kind == "stewart"
    assert load_machine(EXAMPLES / "jugglebot.yaml").kind == "stewart"


# -- through the command line ---------------------------------------------------------------

CLI_CASES = {
    "alias-bomb": (billion_laughs, "aliases"),
    "deep": (lambda: HEAD + "chains: " + "[" * 20000 + "]" * 20000 + "\n", "nested more than"),
    "hexaslide-1e308": (lambda: _chain(HEXA, 2, "l", "1e308"), "chains[2].l: "),
    "delta-1e308": (lambda: _sub(DELTA, "forearm: 800.0", "forearm: 1e308"), "forearm: "),
    "stewart-1e308": (lambda: _leg(CUBIC, 0, "gain", "1e308"), "legs[0].gain: "),
    "hexaslide-same-chain": (lambda: _copy_line(HEXA, 0, 3), "chains[3]: the same chain"),
    "delta-same-angle": (lambda: _sub(DELTA, "[90.0, 180.0, -90.0]", "[90.0, 90.0, -90.0]"),
                         "leg_angles[1]: legs 1 and 2"),
    "stewart-same-leg": (lambda: _copy_line(CUBIC, 1, 4), "legs[4]: the same leg"),
}


@pytest.mark.parametrize("case", list(CLI_CASES))
def test_cli_refuses_with_one_line_and_no_output(tmp_path, case):
    make, words = CLI_CASES[case]
    (tmp_path / "m.yaml").write_text(make())
    (tmp_path / "poses.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n"
                                        "0,0,300,0,0,0\n")
    # counted in this process; as a subprocess (PKMCAL_TEST_SUBPROCESS=1) the work is the
    # child's, and run_process's timeout stops a hang
    with call_budget(CLI_CALLS):
        proc = run("ik", "m.yaml", "poses.csv", "-o", "out.csv", cwd=tmp_path)
    assert_input_error(proc, "m.yaml: ", words)
    assert "Warning" not in proc.stderr
    assert not (tmp_path / "out.csv").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.yaml", "poses.csv"]


def test_cli_refuses_an_oversized_machine_file(tmp_path):
    with open(tmp_path / "m.yaml", "wb") as f:
        f.truncate(2 * 1024**3)
    (tmp_path / "poses.csv").write_text("x_mm,y_mm,z_mm,psi_deg,theta_deg,phi_deg\n"
                                        "0,0,300,0,0,0\n")
    proc = run("ik", "m.yaml", "poses.csv", "-o", "out.csv", cwd=tmp_path)
    assert_input_error(proc, "m.yaml: the machine file is 2147483648 bytes")
    assert not (tmp_path / "out.csv").exists()
