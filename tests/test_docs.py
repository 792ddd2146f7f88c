"""The documentation cannot go stale (issue 26 item 4).

* The site builds: ``mkdocs build --strict`` (every page in the nav, every link resolves, the
  API pages generated from the docstrings without a warning).
* Every shell (```` ```sh ````, ``bash``, ``console``) and Python block of every page (README.md
  and docs/*.md) runs, page by page, in a fresh temporary directory: a page's blocks in order,
  sharing that directory; shell blocks with ``bash -e`` and the virtual environment's ``bin``
  first on the PATH, Python blocks in one process per page. Blocks that are not meant to run
  (output, file contents) are fenced as ``text``, ``yaml``, ``csv``, ...: a fence without a
  language is refused, so "every shell and Python block runs" holds literally.
* A page's blocks never reach into the repository: a file of ``examples/`` a block needs is
  written by an earlier block of the page (a heredoc), and that heredoc must be the example
  file, byte for byte. ``../shared`` (the measured data beside the repository) is reached as
  from the repository's root: the page's directory has a ``../shared`` next to it; a block that
  reads it is skipped (and says so) where the data are absent.

* Output shown after a shell block (a ``text`` block of ``label │ text`` console rows right
  after it) is that block's output: every row shown is a row the commands printed under that
  label, with the same numbers (to the printed digits and 2 %); ``...`` ends what is compared.
* The README's install block (``make demo``, ``. .venv/bin/activate``, ``make test``) is the one
  block run in the repository rather than a fresh directory, and only as ``make -n`` (a dry
  run): ``make test`` runs this very test, ``make demo`` builds the virtual environment.

The figures quoted in the pages' prose are recomputed by tests/test_readme_figures.py,
tests/test_readme_instruments.py and tests/test_readme_planning_figures.py (which read the
pages).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SHELL = {"sh", "bash", "console"}
PYTHON = {"python", "py"}
#: fences that are shown, never run
SHOWN = {"text", "yaml", "csv", "ini", "cfg", "json", "html", "toml", "gcode"}
FENCE = re.compile(r"^```(.*)$")


def blocks(path: Path) -> list[tuple[str, str, int]]:
    """``(language, text, first line)`` of every fenced block of a page, in order."""
    out, lang, body, start = [], None, [], 0
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        m = FENCE.match(line)
        if lang is None:
            if m:
                lang, body, start = m.group(1).strip(), [], number
        elif m and not m.group(1).strip():
            out.append((lang, "\n".join(body) + "\n", start))
            lang = None
        else:
            body.append(line)
    assert lang is None, f"{path.name}: the block of line {start} is not closed"
    return out


def page_id(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def test_every_fence_says_what_it_is():
    """A fence names its language: run (shell, Python) or shown (text, yaml, ...)."""
    for page in PAGES:
        for lang, _, line in blocks(page):
            assert lang in SHELL | PYTHON | SHOWN, (
                f"{page_id(page)}:{line}: fence {lang!r}: say sh/python (run by the tests) or "
                f"text/yaml/csv (shown)")


HEREDOC = re.compile(r"cat > (\S+) <<'(\w+)'\n(.*?)\n\2\n", re.S)


def test_example_files_written_by_the_pages_are_the_examples():
    """A heredoc writing ``NAME`` where ``examples/NAME`` exists writes that file exactly."""
    seen = 0
    for page in PAGES:
        for lang, text, line in blocks(page):
            if lang not in SHELL:
                continue
            for name, _, body in HEREDOC.findall(text):
                example = ROOT / "examples" / name
                if example.is_file():
                    seen += 1
                    assert body + "\n" == example.read_text(encoding="utf-8"), (
                        f"{page_id(page)}:{line}: {name} differs from examples/{name}")
    assert seen >= 4


@pytest.fixture(scope="module")
def pkmcal_bin(tmp_path_factory):
    """A directory whose ``pkmcal`` runs the command in a process forked from a server that
    imported the CLI once (tests/docs_forkserver.py); None with PKMCAL_TEST_SUBPROCESS=1 (the
    virtual environment's console script itself)."""
    if os.environ.get("PKMCAL_TEST_SUBPROCESS") == "1":
        yield None
        return
    d = tmp_path_factory.mktemp("bin")
    sock = str(d / "pkmcal.sock")
    server = subprocess.Popen([sys.executable, str(Path(__file__).with_name(
        "docs_forkserver.py")), sock], env=_env(), stdout=subprocess.PIPE, text=True)
    try:
        assert server.stdout.readline().strip() == "ready"
        script = d / "pkmcal"
        script.write_text(f"#!{sys.executable} -S\nimport sys\n"
                          f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
                          f"from docs_forkserver import client\nclient({sock!r})\n")
        script.chmod(0o755)
        yield d
    finally:
        server.kill()
        server.wait()


def _env() -> dict[str, str]:
    env = dict(os.environ)
    bin_dir = str(Path(sys.executable).parent)
    env["PATH"] = bin_dir + os.pathsep + env.get("PATH", "")
    # the pkmcal of this tree, whichever tree the virtual environment was installed from
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT / "src"), env.get("PYTHONPATH")) if p)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env.setdefault("MKL_NUM_THREADS", "1")
    env.pop("PKMCAL_TEST_SUBPROCESS", None)
    return env


NUMBER = re.compile(r"(?<![\w.])-?\d+(?:\.\d+)?(?:e-?\d+)?")
#: relative slack on a shown figure beyond its printed digits (other BLAS builds)
RTOL = 0.02


def console_rows(text: str) -> list[tuple[str, str]]:
    """``(label, text)`` of console rows ``label │ text``, continuation lines joined."""
    rows: list[list[str]] = []
    for line in text.splitlines():
        if "│" not in line:
            continue
        head, _, tail = line.partition("│")
        if head.strip() or not rows:
            rows.append([head.strip(), tail.strip()])
        else:
            rows[-1][1] += " " + tail.strip()
    return [(label, " ".join(body.split())) for label, body in rows]


def _same_figure(shown: str, got: float) -> bool:
    digits = shown.split("e")[0].partition(".")[2]
    exponent = int(shown.split("e")[1]) if "e" in shown else 0
    half = 0.5 * 10.0 ** (exponent - len(digits))
    return abs(got - float(shown)) <= half + RTOL * abs(float(shown))


def check_output(shown: str, printed: str, where: str) -> int:
    """Every row of ``shown`` is a row of ``printed`` under its label with its figures."""
    tool = console_rows(printed)
    rows = console_rows(shown)
    assert rows, f"{where}: an output block without console rows"
    for label, text in rows:
        want = NUMBER.findall(text.split("...")[0])
        candidates = [body for name, body in tool if name == label]
        assert candidates, f"{where}: no row {label!r} in the output:\n{printed[-3000:]}"
        ok = any(len(got := NUMBER.findall(body)) >= len(want)
                 and all(_same_figure(w, float(g)) for w, g in zip(want, got, strict=False))
                 for body in candidates)
        assert ok, f"{where}: shown {label} │ {text}\nprinted: {candidates}"
    return len(rows)


def _run_python(code: str, cwd: Path, name: str) -> None:
    old = Path.cwd()
    os.chdir(cwd)
    try:
        exec(compile(code, name, "exec"), {"__name__": "__main__"})
    finally:
        os.chdir(old)


def _dry_run_install(text: str, env: dict[str, str]) -> None:
    """The install block's make targets exist and would run; ``.venv`` is the Makefile's."""
    targets = re.findall(r"^make (\w+)", text, re.M)
    assert targets == ["demo", "test"], targets
    assert re.search(r"^\. \.venv/bin/activate", text, re.M)
    assert re.search(r"^VENV\s*:=\s*\.venv$", (ROOT / "Makefile").read_text(), re.M)
    proc = subprocess.run(["make", "-n", *targets], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("page", PAGES, ids=page_id)
def test_every_block_of_the_page_runs(page, tmp_path, pkmcal_bin):
    """The page's shell and Python blocks, in order, in one fresh directory."""
    work = tmp_path / "work"
    work.mkdir()
    if SHARED.is_dir():
        (tmp_path / "shared").symlink_to(SHARED)
    env = _env()
    if pkmcal_bin is not None:
        env["PATH"] = str(pkmcal_bin) + os.pathsep + env["PATH"]
    ran, skipped, timing, checked = 0, [], [], 0
    printed = None          # the output of the shell block just run
    for lang, text, line in blocks(page):
        where = f"{page_id(page)}:{line}"
        if lang == "text" and printed is not None and "│" in text:
            checked += check_output(text, printed, where)
        printed = None
        if lang not in SHELL | PYTHON:
            continue
        if page.name == "README.md" and "make demo" in text:
            _dry_run_install(text, env)
            continue
        if "../shared" in text and not SHARED.is_dir():
            skipped.append(where)
            continue
        t0 = time.perf_counter()
        if lang in SHELL:
            proc = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", text], cwd=work,
                                  env=env, capture_output=True, text=True, timeout=300)
            assert proc.returncode == 0, (
                f"{where}: exit {proc.returncode}\n{text}\nstdout:\n{proc.stdout[-3000:]}\n"
                f"stderr:\n{proc.stderr[-3000:]}")
            printed = proc.stdout
        else:
            _run_python(text, work, where)
        timing.append((time.perf_counter() - t0, where))
        ran += 1
    print(f"{page_id(page)}: {ran} blocks run, {checked} output rows checked, skipped "
          f"{skipped or 'none'}; slowest "
          f"{sorted(timing, reverse=True)[:3]}")


def test_the_site_builds_strictly(tmp_path):
    """``mkdocs build --strict``: nav, links and the API pages from the docstrings."""
    pytest.importorskip("mkdocs", reason="mkdocs is not installed (pip install -e '.[dev]')")
    pytest.importorskip("mkdocstrings", reason="mkdocstrings is not installed")
    env = _env()
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-f",
                           str(ROOT / "mkdocs.yml"), "-d", str(tmp_path / "site")],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-5000:]
    api = (tmp_path / "site" / "api" / "index.html").read_text(encoding="utf-8")
    for name in ("pkmcal.calibration.calibrate", "pkmcal.io.load_machine",
                 "pkmcal.machines.LinearDelta", "pkmcal.planning.select_plan"):
        assert f'id="{name}"' in api, name
