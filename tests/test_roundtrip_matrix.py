"""Every file pkmcal writes is one it accepts (issue 37 item 1): one generated matrix.

For every machine type of the registry (:data:`pkmcal.io.machine_file.MACHINE_FORMATS`, each
with its module's default machine) and every instrument of the registry that applies to it
(:data:`pkmcal.instruments.registry.INSTRUMENTS`), the files the commands write - machine
files from ``simulate --truth``, ``calibrate``, ``import`` of what ``export`` wrote (every
controller format of :data:`pkmcal.export.FORMATS` that holds the machine); data from
``simulate``, ``fk``, ``ik``, ``compensate``, ``select-poses``; ``calibrate``'s JSON report -
are fed to every command that takes that kind of file, and each must accept it (exit 0).
Nothing here names a machine type, an instrument or a format: a new one in a registry is a
new row of the matrix.

The commands run in this process (:func:`clitools.run_in_process`): the CLI start-up would
dominate. The files are made once per machine type (a module fixture, lazily), small plans.
"""

from __future__ import annotations

import functools
from pathlib import Path

import pytest

from clitools import run_in_process as run
from pkmcal.export import FORMATS, load_formats
from pkmcal.instruments.registry import INSTRUMENTS
from pkmcal.io.machine_file import MACHINE_FORMATS, save_machine

#: machine type -> its module's default machine (the registry's own)
DEFAULTS = {kind: fmt.default for kind, fmt in MACHINE_FORMATS.items()}


def test_every_machine_type_has_a_default_machine():
    """The matrix walks the registry: a machine type without a default would be left out."""
    missing = [kind for kind, make in DEFAULTS.items() if make is None]
    assert not missing, missing
    for kind, make in DEFAULTS.items():
        assert make().kind == kind


@functools.cache
def _machine(kind):
    return DEFAULTS[kind]()


def _instruments(kind) -> list[str]:
    machine = _machine(kind)
    return [name for name, inst in INSTRUMENTS.items() if inst.applies(machine) is None]


def _formats(kind) -> list[str]:
    load_formats()                  # the registry fills as the format modules are imported
    machine = _machine(kind)
    return [name for name, fmt in FORMATS.items() if fmt.applies(machine) is None]


def _ok(proc, what):
    assert proc.returncode == 0, f"{what}: exit {proc.returncode}\n{proc.stdout[-2000:]}" \
                                 f"\n{proc.stderr[-2000:]}"
    return proc


class Files:
    """The files of one machine type, written by the commands on first use."""

    def __init__(self, root: Path, kind: str):
        self.d = root / kind
        self.d.mkdir()
        self.kind = kind
        self.machine = _machine(kind)
        save_machine(self.machine, self.d / "nominal.yaml")
        self._done: set = set()

    def cmd(self, *args):
        return run(*args, "-q", cwd=self.d)

    def need(self, key, *args):
        if key not in self._done:
            _ok(self.cmd(*args), " ".join(map(str, args)))
            self._done.add(key)

    # -- writers ---------------------------------------------------------------------------
    def data(self, inst) -> str:
        """``simulate nominal --scenario INST --truth``: the data and the true machine."""
        self.need(("data", inst), "simulate", "nominal.yaml", "--scenario", inst, "--truth",
                  f"{inst}-true.yaml", "-o", f"{inst}.csv")
        return f"{inst}.csv"

    def calibration_files(self, inst) -> list[str]:
        """The data files one calibration of ``inst`` takes: its own file, and beside it the
        first instrument of the registry that completes it (applies, combines with others in
        one fit, and has a plan of more rows than the machine has parameters) when its plan
        has no more rows than that (a plan meant to complete another, e.g. printed-object
        distances beside probe heights)."""
        own = self.data(inst)
        if self._rows(own) > len(self.machine.parameters):
            return [own]
        for other in _instruments(self.kind):
            if other != inst and not INSTRUMENTS[other].joint_refusal and \
                    self._rows(self.data(other)) > len(self.machine.parameters):
                return [self.data(other), own]
        raise AssertionError(f"{inst} on {self.kind}: no instrument completes its plan")

    def _rows(self, name) -> int:
        return (self.d / name).read_text().count("\n") - 1

    def calibrated(self, inst) -> str:
        self.need(("cal", inst), "calibrate", "nominal.yaml", *self.calibration_files(inst),
                  "-o", f"{inst}-cal.yaml")
        return f"{inst}-cal.yaml"

    def machine_file(self, source, inst) -> str:
        """A machine file written by a command: ``truth`` (simulate --truth), ``calibrated``
        (calibrate), ``imported:FORMAT`` (import of what export wrote from the calibrated)."""
        if source == "truth":
            self.data(inst)
            return f"{inst}-true.yaml"
        cal = self.calibrated(inst)
        if source == "calibrated":
            return cal
        fmt = source.split(":", 1)[1]
        out = f"{inst}-{fmt}.export"
        self.need(("export", inst, fmt), "export", cal, "--to", fmt, "-o", out)
        # --like the machine file, as the docs import: a controller file that holds no home
        # pose (genhexkins' HAL) gives forward kinematics no start near the data otherwise
        self.need(("import", inst, fmt), "import", out, "--from", fmt, "--like", "nominal.yaml",
                  "-o", f"{inst}-{fmt}-imported.yaml")
        return f"{inst}-{fmt}-imported.yaml"

    def enough(self) -> int:
        """A number of poses that identifies the machine with any instrument."""
        return len(self.machine.parameters) + 10

    def plan(self, machine="nominal.yaml") -> str:
        """``select-poses`` on a machine file (its own instrument's plan)."""
        name = f"{machine}-plan.csv"
        self.need(("plan", machine), "select-poses", machine, "-n", self.enough(),
                  "--random-sets", 1, "--candidates", 2 * self.enough(), "-o", name)
        return name


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("matrix")
    cache: dict[str, Files] = {}

    def get(kind):
        if kind not in cache:
            cache[kind] = Files(root, kind)
        return cache[kind]
    return get


# -- the consumers: (name, function(files, machine_file, inst) -> arguments) ---------------
def _simulate(f, m, inst):
    return ["simulate", m, "--scenario", inst, "--deviations", "none", "-o", "x.csv"]


def _calibrate(f, m, inst):
    return ["calibrate", m, *f.calibration_files(inst), "-o", "x.yaml"]


def _identifiability(f, m, inst):
    return ["identifiability", m, f.data(inst)]


def _fk(f, m, inst):
    return ["fk", m, f.data(inst), "-o", "x.csv"]


def _fk_instrument(f, m, inst):
    return ["fk", m, f.data(inst), "--frame", "instrument", "--instrument", inst, "-o",
            "x.csv"]


def _ik(f, m, inst):
    return ["ik", m, f.plan(m), "-o", "x.csv"]


def _ik_then_fk(f, m, inst):
    f.need(("ik", m), "ik", m, f.plan(m), "-o", f"{m}-joints.csv")
    return ["fk", m, f"{m}-joints.csv", "-o", "x.csv"]


def _compensate_then_fk(f, m, inst):
    # a printer's plan and compensate's targets are both in its frame (heights above its
    # bed, tilted or not: tests/test_printer_frame.py)
    f.need(("comp", m), "compensate", m, f.plan(m), "-o", f"{m}-commands.csv")
    return ["fk", m, f"{m}-commands.csv", "-o", "x.csv"]


def _compensate_with_report(f, m, inst):
    cal = f.calibrated(inst)
    return ["compensate", cal, f.plan(cal), "--report", cal[:-5] + ".json", "-o", "x.csv"]


def _report(f, m, inst):
    return ["report", f.calibrated(inst)[:-5] + ".json", "-o", "x.html"]


#: consumers of a machine file (with a data file of the instrument that wrote it)
MACHINE_CONSUMERS = {
    "simulate": _simulate, "calibrate": _calibrate, "identifiability": _identifiability,
    "fk": _fk, "ik": _ik, "ik>fk": _ik_then_fk, "compensate>fk": _compensate_then_fk,
}
#: consumers of the instrument's own predictions (need its section in the machine file)
INSTRUMENT_CONSUMERS = {"fk --frame instrument": _fk_instrument}
#: consumers of calibrate's JSON report
REPORT_CONSUMERS = {"report": _report, "compensate --report": _compensate_with_report}


def _cases():
    for kind in DEFAULTS:
        for inst in _instruments(kind):
            sources = ["truth", "calibrated"]
            for source in sources:
                own = INSTRUMENT_CONSUMERS if INSTRUMENTS[inst].section else {}
                for name in (*MACHINE_CONSUMERS, *own):
                    yield pytest.param(kind, inst, source, name,
                                       id=f"{kind}-{inst}-{source}-{name}")
            # every report is read back by compensate; the HTML (slower: plots) of one
            for name in REPORT_CONSUMERS:
                if name == "report" and inst != _machine(kind).default_instrument:
                    continue
                yield pytest.param(kind, inst, "calibrated", name,
                                   id=f"{kind}-{inst}-report-{name}")
        default = _machine(kind).default_instrument
        for fmt in _formats(kind):
            for name in MACHINE_CONSUMERS:
                yield pytest.param(kind, default, f"imported:{fmt}", name,
                                   id=f"{kind}-{default}-imported:{fmt}-{name}")


ALL = {**MACHINE_CONSUMERS, **INSTRUMENT_CONSUMERS, **REPORT_CONSUMERS}


@pytest.mark.parametrize(("kind", "inst", "source", "consumer"), list(_cases()))
def test_every_written_file_is_accepted(files, kind, inst, source, consumer):
    f = files(kind)
    m = f.machine_file(source, inst)
    args = ALL[consumer](f, m, inst)
    _ok(f.cmd(*args), f"{source} file of {kind}/{inst} -> {' '.join(map(str, args))}")


@pytest.mark.parametrize("kind", list(DEFAULTS))
def test_a_plan_is_accepted(files, kind):
    """``select-poses``'s plan: analysed again (``identifiability --planned``), and its poses
    taken by ``ik`` and as candidates of ``select-poses --from``."""
    f = files(kind)
    plan = f.plan()
    _ok(f.cmd("identifiability", "nominal.yaml", plan, "--planned"), "identifiability")
    _ok(f.cmd("ik", "nominal.yaml", plan, "-o", "x.csv"), "ik of the plan")
    _ok(f.cmd("select-poses", "nominal.yaml", "--from", plan, "-n", f.enough(),
              "--random-sets", 1,
              "-o", "x.csv"), "select-poses --from the plan")


#: formats no registry default machine fits, and where their round trips are tested instead:
#: LinuxCNC's rotarydeltakins holds only its own leg layout (hips at -90, 30, 150 deg), not
#: seed 001's default Delta (90, 180, -90)
ELSEWHERE = {"linuxcnc-rotarydelta": "tests/test_exports_unseen.py, tests/test_linuxcnc_kins.py"}


def test_the_matrix_covers_every_registry_member():
    """Every machine type, every instrument and every controller format has a row (or a
    named test file that round-trips it on machines of its layout)."""
    cases = [p.values for p in _cases()]
    assert {c[0] for c in cases} == set(DEFAULTS)
    assert {c[1] for c in cases} == set(INSTRUMENTS)
    load_formats()
    covered = {c[2].split(":", 1)[1] for c in cases if c[2].startswith("imported:")}
    assert covered | set(ELSEWHERE) == set(FORMATS)
    assert not covered & set(ELSEWHERE)
    root = Path(__file__).resolve().parents[1]
    assert all((root / f).is_file() for files in ELSEWHERE.values() for f in files.split(", "))


def test_a_printers_bed_height_is_carried_by_its_endstops(tmp_path):
    """Issue 37: a true printer written with ``bed: {height: 0.5}`` was refused by
    ``simulate`` ("the bed's centre (0, 0, 0) mm cannot be probed"): a printer's frame is its
    bed, so the height is read as what it means - the endstops 0.5 mm nearer the bed - and
    never written."""
    from pkmcal.io import load_machine_file

    printer = next(make() for make in DEFAULTS.values() if make().frame_is_bed)
    save_machine(printer, tmp_path / "printer.yaml")
    text = (tmp_path / "printer.yaml").read_text()
    assert "bed:" not in text
    (tmp_path / "raised.yaml").write_text(text + "bed: {height: 0.5, tilt_x: 0.001, "
                                                 "tilt_y: 0.0}\n")
    raised, setups = load_machine_file(tmp_path / "raised.yaml")
    assert setups["probe"].plane == (0.0, 0.001, 0.0)
    P, R = printer.home
    q0, q1 = printer.ik(P[None], R[None]), raised.ik(P[None] - [0, 0, 5e-4], R[None])
    assert abs(q1 - q0).max() <= 1e-12 * abs(q0).max()       # the same printer, 0.5 mm lower
    _ok(run("simulate", "raised.yaml", "--deviations", "none", "-o", "s.csv", cwd=tmp_path),
        "simulate of a raised bed")
    _ok(run("simulate", "raised.yaml", "--truth", "again.yaml", "-o", "s.csv",
            cwd=tmp_path), "simulate --truth")
    again = (tmp_path / "again.yaml").read_text()
    assert "height: 0.0," in again
