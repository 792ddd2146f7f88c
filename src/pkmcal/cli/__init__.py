"""The ``pkmcal`` command (SPEC 6): one sub-command per task, a thin layer over the library.

Start-up cost matters (``pkmcal calibrate`` must finish in well under a second), so this module
imports only typer; numpy, PyYAML, pydantic and the library (each command's work is a function
of :mod:`pkmcal.workflows`) are imported inside the commands, and neither scipy nor
matplotlib is imported here.

Exit codes: 0 success; 1 the computation ran but did not succeed (e.g. calibration did not
converge, a benchmark missed its target); 2 bad input (a file, row, column, key or option is
named on one line on stderr; no traceback, no output file written).
"""

from __future__ import annotations

import enum
import functools
import inspect
import os
import sys
from pathlib import Path
from typing import Annotated

import typer

from ..errors import (
    ConvergenceError,
    InputError,
    Terminated,
    forget_signals,
    handle_signals,
    interruption,
    interruption_exit,
    restore_signals,
)
from ..limits import MAX_MEASUREMENTS, MAX_RUNS, MAX_SAMPLES
from ..paths import path_text
from ..workflows.names import formats, machine_types

app = typer.Typer(
    name="pkmcal",
    help="Calibration, identifiability and error analysis of parallel kinematic machines.\n\n"
         f"MACHINE arguments are a machine file (YAML, `machine:` {machine_types()}; "
         "examples/) or the word 'default' for the embedded Hexa Slide "
         "(examples/delta_default.yaml is the default Delta). Numbers on the command line "
         "take a unit suffix (2um, 300mm, 10deg); a bare number is SI.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="markdown",
    context_settings={"help_option_names": ["-h", "--help"]},
)


class Deviations(enum.StrEnum):
    paper_table1 = "paper-table1"
    none = "none"
    random = "random"


class TargetFrame(enum.StrEnum):
    base = "base"
    instrument = "instrument"


MachineArg = Annotated[str, typer.Argument(
    metavar="MACHINE", help=f"Machine file (YAML, machine: {machine_types()}) or 'default' "
                            "for the embedded Hexa Slide.",
    show_default=False)]
def _file_name(text: str) -> Path:
    """An output file's name as typed: ``out.csv/`` names a directory (Path would drop the
    slash and write ``out.csv``), refused like the shell refuses ``> out.csv/``."""
    if text.endswith(("/", os.sep)):
        raise typer.BadParameter(f"{text}: ends with '/', which names a directory; give a "
                                 "file name")
    return Path(text)


OutFile = Annotated[Path, typer.Option("-o", "--output", help="Output file (written atomically).",
                                       show_default=False, parser=_file_name, metavar="FILE")]


# -- options shared by the commands that read data files or predict accuracy (issue 12.7) ----
def _column_map(value: str | None) -> str | None:
    """``--columns``: from here on, data files are read with their columns renamed."""
    if value is not None:
        from ..io.csv_io import parse_column_map, set_column_map

        set_column_map(parse_column_map(value))
    return value


def _reset_column_map() -> None:
    """No column map outside the command that set one (main() may run several in a row)."""
    module = sys.modules.get("pkmcal.io.csv_io")
    if module is not None:
        module.set_column_map(None)


ColumnsOpt = Annotated[str | None, typer.Option(
    "--columns", metavar="MAP", callback=_column_map, show_default=False,
    help="Rename the data file's columns to pkmcal's names before reading, for files from "
         "other tools: comma-separated pairs PKMCAL=FILE, left pkmcal's name with its unit, "
         "right the file's column, e.g. q1_rev=leg_length_1 (and so on per leg), "
         "x_mm=position_x, qx=orientation_x. A name pkmcal does not read, or a column the "
         "file does not have, is refused.")]
WorkspaceOpt = Annotated[str | None, typer.Option(
    "--workspace", metavar="BOX|POINTS.csv", show_default=False,
    help="Where the predicted accuracy is evaluated (default: the 0.1 m cube around home, "
         "orientations within +/-10 deg): a box X0,X1,Y0,Y1,Z0,Z1 with units (e.g. "
         "'-50mm, 50mm, -50mm, 50mm, 250mm, 350mm'; orientations as by default), or a CSV of "
         "points `x_<len>, y_<len>, z_<len>` [+ `psi/theta/phi_<ang>` or qx..qw]; a printer's "
         "z is the height above its bed.")]


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        typer.echo(f"pkmcal {version('pkmcal')}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                          help="Show the version and exit.")] = False,
    quiet: Annotated[bool, typer.Option(
        "--quiet", "-q", help="Print nothing but errors and warnings (files are still "
                              "written; --json output is still printed).")] = False,
) -> None:
    """Calibration, identifiability and error analysis of parallel kinematic machines."""
    if quiet:
        from ._console import set_quiet

        set_quiet()


@app.command()
def demo(
    output: Annotated[Path, typer.Option("-o", "--output", file_okay=False,
                                         help="Directory for the demo's files.")]
    = Path("pkmcal-demo"),
) -> None:
    """Run the main job on the embedded defaults: simulate, calibrate, compare. No input needed.

    Fixed seeds: the settings of every case (seed, noise, poses, deviations) are printed first
    and written to summary.json; the Hexa Slide case is seed 0 of the researcher's page's table.

    Example: `pkmcal demo -o demo-out`
    """
    from ..workflows.demo import demo as run
    from ._console import print_summary, progress_tasks

    with progress_tasks() as new:
        summary = run(output, progress=new)
    raise typer.Exit(print_summary(summary))


@app.command()
def simulate(
    machine: MachineArg,
    output: OutFile,
    scenario: Annotated[str | None, typer.Option(metavar="SCENARIO",
        help="Measurement scenario (instrument), on every machine it applies to: "
             "constraint-link (a platform that rotates with `constraint_link` in its file), "
             "tracker = points (laser tracker, every machine), pose = poses (motion capture, "
             "a platform that rotates), distance = distances = ballbar (every machine). "
             "Default: the machine type's own (e.g. constraint-link on a hexaslide, tracker "
             "on a delta, pose on a stewart, probe on a linear_delta).",
        show_default=False)] = None,
    poses: Annotated[int | None, typer.Option(
        min=1, max=MAX_MEASUREMENTS,
        help="Number of measurement poses (constraint-link: default 150; pose: 60; points on "
             "a platform that rotates: 60 random workspace poses with rotations; distance: "
             "90).", show_default=False)] = None,
    noise: Annotated[str | None, typer.Option(
        help="Measurement noise. constraint-link: encoder noise, standard deviation (default "
             "2um). tracker: leica (default; 5 um along the beam, 7.5 um + 3 um/m across), "
             "none, or a length for isotropic noise (e.g. 10um). pose: noise of the leg "
             "readings, as a leg length (default 2um). distance: ballbar length noise "
             "(default 1um).", show_default=False)] = None,
    targets: Annotated[int | None, typer.Option(
        min=1, max=100,
        help="points on a platform that rotates: number of targets (reflector nests); rows "
             "cycle through them (column `target`); each true place is off the platform "
             "origin by a random mounting error.", show_default=False)] = None,
    setups: Annotated[int | None, typer.Option(
        min=1, max=100,
        help="distance: number of ballbar mountings (default 3; column `setup`); true pivots "
             "and balls = planned + a random 1 mm mounting error.", show_default=False)]
    = None,
    radius: Annotated[str | None, typer.Option(
        help="distance: the ballbar length (default 100mm): poses on the spheres of this "
             "radius around each setup's pivot.", show_default=False)] = None,
    circles: Annotated[bool, typer.Option(
        "--circles", help="distance: ISO 230-4 circles (one per setup, home orientation) "
                          "instead of random poses on the spheres.")] = False,
    pose_noise: Annotated[str | None, typer.Option(
        "--pose-noise", help="pose: noise of the measured poses, POSITION,ORIENTATION with "
                             "units (default 20um,50urad).", show_default=False)] = None,
    lc_error: Annotated[str, typer.Option(
        "--lc-error", help="Error of the constraint-link length in the machine file: the true "
                           "link is the file's length minus this.")] = "0um",
    seed: Annotated[int, typer.Option(
        min=0, help="Random seed (poses, noise, random deviations).")] = 0,
    deviations: Annotated[Deviations | None, typer.Option(
        help="True machine = MACHINE + deviations: paper-table1 (seed 000 Table 1), none, "
             "or random (uniform per error within the machine type's half-widths, e.g. "
             "hexaslide: lengths +/-2 mm, angles +/-0.02 rad; delta: +/-1 mm, +/-0.5 deg). "
             "Default: paper-table1 on a hexaslide, random on the others.",
        show_default=False)] = None,
    grid: Annotated[str | None, typer.Option(
        help="tracker: points commanded on an NXxNYxNZ grid with dx = dy = 150 mm, dz = 40 mm, "
             "centred at the machine's home (default 3x3x3, seed 001).",
        show_default=False)] = None,
    outliers: Annotated[int, typer.Option(
        min=0, max=MAX_MEASUREMENTS,
        help="tracker: corrupt this many random points by 1 mm (beam breaks, a "
                    "mis-seated reflector); their rows are printed.")] = 0,
    truth: Annotated[Path | None, typer.Option(
        parser=_file_name, metavar="FILE",
        help="Also save the simulated true machine here (YAML; for a tracker scenario with "
             "the true tracker pose).")] = None,
) -> None:
    """Simulate measurements of a true machine (MACHINE + deviations); write a data file.

    constraint-link (Hexa Slide): joint readings q1..q6 in the machine file's length unit and
    the passive actuator (1..6) of each pose.

    tracker (Delta, seed 001): the nominal model commands the grid points, the true machine
    goes elsewhere, a laser tracker measures the reflector (smr_offset below the platform
    point). Columns q1..q3 (arm angles, the file's angle unit) and mx, my, mz (tracker frame,
    the file's length unit). The true tracker pose is the machine file's `tracker` section,
    else the default: 2.5 m from the robot's axis at (2.0, -1.5, -1.4) m in the base frame,
    turned 143.13 deg about Z to face the robot and tilted 1 deg.

    Example: `pkmcal simulate default --poses 150 --noise 1um --truth true.yaml -o data.csv`

    Example: `pkmcal simulate examples/delta_default.yaml --scenario tracker --seed 1
    --truth true.yaml -o tracker.csv`

    pose (six-leg platform): random platform poses in the 0.1 m cube around home
    with Euler angles within +/-10 deg; the legs' readings q1..q6 (the machine's reading unit)
    and the marker pose measured by a motion-capture system, x, y, z (the file's length unit)
    and qx, qy, qz, qw, in the measurement frame. The true frames are the machine file's
    measurement_frames, else the default (the base origin measured at (1200, -400, -300) mm,
    turned 30 deg about Z and tilted 2 deg; marker 25 mm off the platform origin, turned 90 deg).

    Example: `pkmcal simulate examples/cubic_6upu.yaml --scenario pose --poses 60 --truth
    true.yaml -o poses.csv`

    points on a platform that rotates (Hexa Slide, Stewart): random workspace poses with
    rotations; readings q1..qn and mx, my, mz (the file's length unit), `target` with
    --targets. distance (every machine): readings and the ballbar length d between a pivot
    on the base and a ball on the platform, `setup` with several mountings. pose works on
    every platform that rotates, constraint-link on every one with `constraint_link`.

    Example: `pkmcal simulate examples/cubic_6upu.yaml --scenario points --targets 2 -o
    points.csv`

    Example: `pkmcal simulate default --scenario distance --setups 4 --radius 150mm -o
    ballbar.csv`
    """
    from ..workflows.simulate import simulate as run
    from ._console import print_summary

    raise typer.Exit(print_summary(run(
        machine, output, scenario, poses, noise, lc_error, seed,
        deviations.value if deviations else None, truth, grid, outliers,
        pose_noise=pose_noise, targets=targets, setups=setups, radius=radius,
        circles=circles)))


class _WithInstrumentOptions:
    """A command whose options are its function's and those the instruments declare in their
    modules (:func:`pkmcal.calibration.options.command_options`): typer reads them from the
    signature, built when typer first asks (the registry is imported only for this command
    or the app's help), and the function receives them as keywords."""

    def __init__(self, func):
        self._signature = self._doc = None
        functools.update_wrapper(self, func)

    @property
    def __doc__(self) -> str:
        """The command's help: its function's, then each instrument's paragraphs
        (:func:`pkmcal.calibration.options.calibrate_help`), composed when typer first asks."""
        if self._doc is None:
            from ..calibration.options import calibrate_help

            extra = calibrate_help()
            self._doc = inspect.cleandoc(self._base_doc) + (f"\n\n{extra}" if extra else "")
        return self._doc

    @__doc__.setter
    def __doc__(self, text) -> None:
        self._base_doc, self._doc = text or "", None

    def __call__(self, *args, **kwargs):
        return self.__wrapped__(*args, **kwargs)

    @property
    def __signature__(self) -> inspect.Signature:
        if self._signature is None:
            from ..calibration.options import command_options

            own = inspect.signature(self.__wrapped__, eval_str=True)
            params = [p for p in own.parameters.values() if p.kind is not p.VAR_KEYWORD]
            for opt in command_options():
                params += _instrument_parameters(opt)
            names = [p.name for p in params]
            assert len(names) == len(set(names)), names
            self._signature = own.replace(parameters=params)
        return self._signature


def _instrument_parameters(opt) -> list[inspect.Parameter]:
    """The command's parameters of one instrument option (a ``--x/--no-x`` pair as two flags:
    a pair widens every row of the help at 80 columns; a text as a list, given at most
    once)."""
    def keyword(name, annotation, default):
        return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default,
                                 annotation=annotation)

    if opt.kind == "text":
        return [keyword(opt.name, Annotated[list[str] | None, typer.Option(
            opt.flag, metavar=opt.metavar, help=opt.help, show_default=False)], None)]
    out = [keyword(opt.name, Annotated[bool, typer.Option(opt.flag, help=opt.help)], False)]
    if opt.kind == "either":
        out.append(keyword("no_" + opt.name, Annotated[bool, typer.Option(
            opt.negative, help=opt.negative_help)], False))
    return out


def _noise_help() -> str:
    from ..calibration.options import noise_help

    return noise_help()


@app.command()
@_WithInstrumentOptions
def calibrate(
    machine: MachineArg,
    data: Annotated[list[Path], typer.Argument(
        metavar="DATA...", show_default=False,
        help="Measurement file(s) (CSV). Several files of instrument kinds (tracker points, "
             "ballbar distances, ...) are fitted together: one geometry, each file with its "
             "own instrument unknowns and noise.")],
    output: OutFile,
    noise: Annotated[list[str] | None, typer.Option(
        metavar="NOISE",
        help="Measurement noise, held as given. Without it the noise levels are estimated "
             "from the residuals (the defaults below are the start and are kept where the data "
             "cannot check them; the report's noise_model section). With several data files: "
             "FILE=VALUE, once per file (e.g. --noise bar.csv=2um --noise pts.csv=leica); "
             "files not named have their levels estimated. " + _noise_help(),
        show_default=False)] = None,
    report: Annotated[Path | None, typer.Option(
        "--report", metavar="DIR", file_okay=False,
        help="Also write DIR/report.html (self-contained: tables and plots) and its JSON twin "
             "DIR/report.json (DIR is created when missing).", show_default=False)] = None,
    parameters: Annotated[str | None, typer.Option(
        "--parameters", metavar="NAME",
        help="Fit the machine's named parameter set NAME (e.g. a firmware's: klipper, marlin, "
             "rrf, full on a linear Delta): its fixed flags replace the machine file's. "
             "auto (a linear Delta's default): the candidate models are fitted and the one "
             "with the smallest leave-one-out prediction error is kept, named in the report.",
        show_default=False)] = None,
    robust: Annotated[bool, typer.Option(
        "--robust", help="Leave out the rows the noise cannot explain (a chi-square test "
                         "of each row; named by file row in any case, left out with this "
                         "option) and fit again; every instrument (ml methods).")] = False,
    holdout: Annotated[str | None, typer.Option(
        "--holdout", metavar="F",
        help="Hold out a random share of the rows (0.2 or 20%) or a number of them (30): "
             "calibrate on the rest and report the held-out residuals before and after "
             "calibration (the report's validation section).", show_default=False)] = None,
    seed: Annotated[int, typer.Option(
        min=0, metavar="N", help="Seed of the random choice of held-out rows (--holdout); "
                                 "a whole number, 0 or more.")] = 0,
    json_output: Annotated[bool, typer.Option(
        "--json", help="Print the JSON report on stdout instead of the summary.")] = False,
    columns: ColumnsOpt = None,
    **options,
) -> None:
    """Identify the geometry from measurements; write the calibrated machine and a report.

    The measurement type follows from the data file's columns (each instrument's below).
    Writes the calibrated machine file (-o) and a JSON report beside it (same name, .json).

    Example: `pkmcal calibrate default data.csv -o calibrated.yaml`

    Example: `pkmcal calibrate default data.csv -o cal.yaml --holdout 0.2 --report rep/`

    Several files of the instruments that combine: one fit of the geometry with every file's
    own instrument unknowns (named FILE:name) and noise (--noise FILE=VALUE); the summary
    shows each file's residuals before and after, what the files cannot fix together and what
    each file adds; --holdout holds out rows of every file.

    Example: `pkmcal calibrate machine.yaml first.csv second.csv --noise second.csv=2um
    -o cal.yaml`
    """
    from ..calibration.options import command_values
    from ..workflows.calibrate import calibrate_files
    from ._console import print_summary

    try:
        summary = calibrate_files(machine, data, output, noise, json_output, robust, report,
                                  holdout, seed, parameters, command_values(options))
    except ConvergenceError as exc:     # the fit ran and did not succeed: exit 1, nothing written
        from ._console import error

        error(str(exc))
        raise typer.Exit(1) from None
    raise typer.Exit(print_summary(summary))


@app.command()
def check(
    machine: MachineArg,
    data: Annotated[list[Path], typer.Argument(
        metavar="DATA...", show_default=False,
        help="Data the machine was not fitted to: measurement files (CSV) of any instrument, "
             "a Klipper printer.cfg and its backups (their saved points and bed meshes), a "
             "pasted probe report.")],
    noise: Annotated[list[str] | None, typer.Option(
        help="The data's noise, FILE=VALUE per file (e.g. --noise probe.csv=20um); default "
             "each instrument's. The verdict is against it.", show_default=False)] = None,
    output: Annotated[Path | None, typer.Option(
        "-o", "--output", parser=_file_name, metavar="FILE", show_default=False,
        help="Also write the check's report (JSON).")] = None,
) -> None:
    """Score a calibrated or imported machine on data it was not fitted to.

    The machine's parameters are held; each file keeps its instrument's unknowns and one free
    offset (a probe's trigger height, a mesh's reference), as the next-session test scores a
    session. Prints per file the residuals (RMS, largest), their size against the data's
    noise and the verdict; for a printer's saved configs (sessions) also each session's
    endstop drift since the calibration. Exit 0 whatever the verdict; 2 on bad input.

    Example: `pkmcal check calibrated.yaml printer.cfg` (and `pkmcal check printer.yaml
    printer.cfg` for the values in force, to compare)
    """
    from ..workflows.check import check as run
    from ._console import print_summary

    raise typer.Exit(print_summary(run(machine, data, noise, output)))


@app.command()
def identifiability(
    machine: MachineArg,
    data: Annotated[Path | None, typer.Argument(
        metavar="[DATA]", show_default=False,
        help="Measurement file (CSV); with --planned a plan (poses only); without it, random "
             "planned poses.")] = None,
    planned: Annotated[bool, typer.Option(
        "--planned", help="DATA holds planned poses (x, y, z and psi, theta, phi or qx..qw; "
                          "a printer's z the height above its bed; "
                          "other columns ignored), not measurements: analyse the measurements "
                          "the machine file's geometry would give there (e.g. the output of "
                          "select-poses).")] = False,
    poses: Annotated[int | None, typer.Option(
        min=1, max=MAX_MEASUREMENTS,
        help="Without DATA: the number of random planned poses (default: 150 constraint-link, "
             "60 pose; tracker: seed 001's 3x3x3 grid around home).", show_default=False)]
    = None,
    seed: Annotated[int, typer.Option(
        min=0, help="Seed of random planned poses and of the workspace sample.")] = 0,
    noise: Annotated[str | None, typer.Option(
        help="Measurement noise of the prediction, as in calibrate (constraint-link: encoder "
             "std, default 1um; tracker: leica or a length; pose: leg readings, default 2um).",
        show_default=False)] = None,
    pose_noise: Annotated[str | None, typer.Option(
        "--pose-noise", help="pose measurements: noise of the measured poses, "
                             "POSITION,ORIENTATION (default 20um,50urad).",
        show_default=False)] = None,
    map_path: Annotated[Path | None, typer.Option(
        "--map", parser=_file_name, metavar="PNG",
        help="Write a map (PNG) of the predicted position error over two workspace slices "
             "through home.", show_default=False)] = None,
    json_output: Annotated[bool, typer.Option(
        "--json", help="Print the report as JSON (keys parameters, identifiable, "
                       "unidentifiable, observability, condition_number, hold_fixed, "
                       "correlated, predicted_accuracy, singular_values).")] = False,
    columns: ColumnsOpt = None,
    workspace: WorkspaceOpt = None,
    scenario: Annotated[str | None, typer.Option(metavar="SCENARIO",
        help="Without DATA or with --planned: the instrument (constraint-link, tracker = "
             "points, pose = poses, distance = distances = ballbar) on any machine it applies "
             "to; default the machine type's own (e.g. constraint-link on a hexaslide, "
             "tracker on a delta, pose on a stewart, probe on a linear_delta). With "
             "measurements it follows from the columns.",
        show_default=False)] = None,
    setups: Annotated[int | None, typer.Option(
        min=1, max=100, help="distance plans: number of ballbar mountings (default 3).",
        show_default=False)] = None,
    radius: Annotated[str | None, typer.Option(
        help="distance plans: the ballbar length (default 100mm); poses on the spheres of "
             "this radius around the pivots.", show_default=False)] = None,
    targets: Annotated[int | None, typer.Option(
        min=1, max=100, help="tracker plans: number of targets on the platform, poses "
             "cycling through them (default 1).", show_default=False)] = None,
    parameters: Annotated[str | None, typer.Option(
        "--parameters", metavar="NAME",
        help="Analyse the machine's named parameter set NAME (a firmware's: klipper, marlin, "
             "rrf, full on a linear Delta), as calibrate --parameters fits it.",
        show_default=False)] = None,
) -> None:
    """What the measurements will identify and how accurate the calibration will be.

    From measurements (DATA; the type follows from the columns, as in `pkmcal calibrate`), from
    planned poses (`--planned DATA`), or, without DATA, from random planned poses of the
    machine type's own scenario (see --scenario). The problem is evaluated at the machine
    file's geometry; on its scaled reduced Jacobian: the number of identifiable parameter
    directions, the unidentifiable ones in words (frame gauges first, then parameter
    combinations), observability indices O1..O5, the condition number, a minimal identifiable
    set (parameters to hold fixed; QR with column pivoting), parameter pairs correlated beyond
    0.9, and the predicted pose accuracy after calibration (Cramer-Rao bound with the --noise
    model, propagated to the 0.1 m workspace cube around home; frames the data cannot fix
    removed by a best fit).

    Example: `pkmcal identifiability default data.csv`

    Example: `pkmcal identifiability default --poses 60 --noise 2um --map predicted.png`

    Example: `pkmcal identifiability examples/delta_default.yaml plan.csv --planned --json`

    Every instrument on every machine it applies to: measurements of points (mx, my, mz
    [+ target]), distances (d [+ setup]), poses or constraint-link readings, or a plan of
    `--scenario` (its setup / target column kept).

    Example: `pkmcal identifiability examples/cubic_6upu.yaml --scenario distance --setups 4`
    """
    from ..workflows.planning import identifiability as run
    from ._console import print_summary

    raise typer.Exit(print_summary(run(
        machine, data, json_output=json_output, planned=planned, poses=poses, seed=seed,
        noise=noise, pose_noise=pose_noise, map_path=map_path, workspace=workspace,
        scenario=scenario, setups=setups, radius=radius, targets=targets,
        parameters=parameters)))


class Criterion(enum.StrEnum):
    d = "d"
    a = "a"
    pose = "pose"


@app.command("select-poses")
def select_poses(
    machine: MachineArg,
    output: OutFile,
    n: Annotated[int, typer.Option("-n", "--poses", help="Number of poses to choose.",
                                   min=1, max=MAX_MEASUREMENTS, show_default=False)],
    candidates: Annotated[int, typer.Option(
        min=1, max=MAX_MEASUREMENTS,
        help="Number of random feasible candidates (constraint-link: on the sphere |P| = Lc; "
             "tracker: in the box of the 3x3x3 grid around home; pose: the 0.1 m cube, +/-10 "
             "deg).")] = 2000,
    candidates_file: Annotated[Path | None, typer.Option(
        "--from", help="Choose among the poses of this file instead (x, y, z + orientation; "
                       "every pose must be reachable; a printer's in its frame, as the plan "
                       "written).", show_default=False)] = None,
    joint_range: Annotated[str | None, typer.Option(
        "--joint-range", metavar="MIN,MAX",
        help="Joint limits, e.g. 100mm,600mm (slider travel) or -60deg,90deg (Delta arms): "
             "candidates needing a joint outside are left out.", show_default=False)] = None,
    criterion: Annotated[Criterion, typer.Option(
        help="d: D-optimal (maximise det of the information, observability index O1); a: "
             "A-optimal (mean parameter variance); pose: smallest predicted mean squared "
             "position error over the workspace.")] = Criterion.d,
    random_sets: Annotated[int, typer.Option(
        min=0, max=MAX_RUNS, help="Random sets of the same size to compare against.")] = 100,
    noise: Annotated[str | None, typer.Option(
        help="Measurement noise of the prediction (as in calibrate).", show_default=False)]
    = None,
    pose_noise: Annotated[str | None, typer.Option(
        "--pose-noise", help="pose measurements: noise of the measured poses.",
        show_default=False)] = None,
    seed: Annotated[int, typer.Option(
        min=0, help="Seed of the candidates, the workspace sample and the random sets.")] = 0,
    map_path: Annotated[Path | None, typer.Option(
        "--map", parser=_file_name, metavar="PNG",
        help="Write a map (PNG) of the predicted position error with the chosen poses.",
        show_default=False)] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print the report as JSON.")]
    = False,
    columns: ColumnsOpt = None,
    workspace: WorkspaceOpt = None,
    scenario: Annotated[str | None, typer.Option(metavar="SCENARIO",
        help="The instrument (constraint-link, tracker = points, pose = poses, distance = "
             "distances = ballbar) on any machine it applies to; default the machine's.",
        show_default=False)] = None,
    setups: Annotated[int | None, typer.Option(
        min=1, max=100, help="distance: number of ballbar mountings (default 3); the "
             "candidates lie on the spheres around their pivots, the plan keeps the setup "
             "column.", show_default=False)] = None,
    radius: Annotated[str | None, typer.Option(
        help="distance: the ballbar length (default 100mm), the radius of the candidate "
             "spheres around the pivots.", show_default=False)] = None,
    targets: Annotated[int | None, typer.Option(
        min=1, max=100, help="tracker: number of targets on the platform; candidates cycle "
             "through them and the plan keeps the target column.", show_default=False)]
    = None,
    parameters: Annotated[str | None, typer.Option(
        "--parameters", metavar="NAME",
        help="Analyse the machine's named parameter set NAME (a firmware's: klipper, marlin, "
             "rrf, full on a linear Delta), as calibrate --parameters fits it.",
        show_default=False)] = None,
) -> None:
    """Choose N measurement poses that identify the machine best.

    Candidates are feasible poses of the machine's scenario (reachable, well conditioned;
    constraint link: drivable with the link mounted; within --joint-range) or the poses of
    --from. The choice
    maximises a design criterion on the information of the scaled identification Jacobian
    (greedy and the instrument's standard plan as starts, then exchanges until none improves
    it; never worse than the standard plan, e.g. seed 001's 3x3x3 grid for a tracker), and
    the report compares its predicted accuracy after calibration with the standard plan and
    with random sets of the same size. Writes the chosen poses
    (the file's units; a printer's in its frame, z the height above its bed, its probe points
    at z = 0) with the joint values that reach them on the nominal machine and the
    candidate row; `pkmcal identifiability MACHINE PLAN.csv --planned` analyses it again.

    Example: `pkmcal select-poses default -n 60 -o plan.csv --map plan.png`

    Example: `pkmcal select-poses examples/delta_default.yaml -n 27 --noise 10um -o plan.csv`

    Example: `pkmcal select-poses default --scenario distance --radius 150mm -n 40 -o
    ballbar-plan.csv`
    """
    from ..workflows.planning import select_poses as run
    from ._console import print_summary, progress_tasks

    with progress_tasks() as new:
        summary = run(machine, output, n, candidates=candidates,
                      candidates_path=candidates_file, criterion=criterion.value,
                      random_sets=random_sets, noise=noise, pose_noise=pose_noise, seed=seed,
                      map_path=map_path, json_output=json_output, joint_range=joint_range,
                      workspace=workspace, scenario=scenario, setups=setups, radius=radius,
                      targets=targets, parameters=parameters, progress=new)
    raise typer.Exit(print_summary(summary))


@app.command()
def fk(
    machine: MachineArg,
    joints: Annotated[Path, typer.Argument(
        metavar="JOINTS.csv", show_default=False,
        help="Joint readings `q1_<unit>..q6_<unit>` (Delta: q1_deg..q3_deg; Stewart: the legs' "
             "reading unit, e.g. q1_rev; other columns are ignored).")],
    output: OutFile,
    frame: Annotated[TargetFrame, typer.Option(
        help="base: platform poses in the base frame (a printer's: its frame, z the height "
             "above its bed). instrument: what the calibration's "
             "instrument measures for these readings, from the calibrated file's tracker "
             "(mx, my, mz of the target in the tracker frame; column target 1..K picks the "
             "target), measurement_frames (x, y, z, qx, qy, qz, qw of the marker in the "
             "motion-capture frame) or ballbar (d per column setup 1..K) section: compare them "
             "with new measurements to check a calibration.")] = TargetFrame.base,
    instrument: Annotated[str | None, typer.Option(
        metavar="tracker|pose|distance",
        help="With --frame instrument, when the file carries several instruments: which one "
             "(aliases points, poses, ballbar).", show_default=False)] = None,
    columns: ColumnsOpt = None,
) -> None:
    """Forward kinematics: poses from joint readings, in the machine file's units.

    Writes x, y, z and psi, theta, phi (R = RY(theta) RX(psi) RZ(phi)) per row; for a Delta
    (the platform only translates) x, y, z of the platform point in the base frame (a
    printer: in its frame, z the height above its bed). With
    --frame instrument: the instrument's predicted measurements in the file's length unit.

    Example: `pkmcal fk calibrated.yaml joints.csv -o poses.csv`

    Example: `pkmcal fk calibrated.yaml new_readings.csv --frame instrument -o predicted.csv`
    """
    from ..workflows.kinematics import fk as run
    from ._console import print_summary

    raise typer.Exit(print_summary(run(machine, joints, output, TargetFrame(frame).value,
                                       instrument)))


@app.command()
def ik(
    machine: MachineArg,
    poses: Annotated[Path, typer.Argument(
        metavar="POSES.csv", show_default=False,
        help="Poses `x_<unit>, y_<unit>, z_<unit>` + `psi/theta/phi_<unit>` or qx, qy, qz, qw "
             "(Delta: x, y, z only), in the base frame (a printer: its frame, z the height "
             "above its bed).")],
    output: OutFile,
    columns: ColumnsOpt = None,
) -> None:
    """Inverse kinematics: joint values that put the platform at the given poses.

    Writes q1..q6 in the machine file's length unit (Delta: arm angles q1..q3 in its angle
    unit; Stewart: leg readings in its reading unit, e.g. q1_rev).

    Example: `pkmcal ik calibrated.yaml poses.csv -o joints.csv`
    """
    from ..workflows.kinematics import ik as run
    from ._console import print_summary

    raise typer.Exit(print_summary(run(machine, poses, output)))


@app.command()
def compensate(
    machine: Annotated[str, typer.Argument(
        metavar="CALIBRATED", show_default=False,
        help="The calibrated machine file (from pkmcal calibrate).")],
    targets: Annotated[Path, typer.Argument(
        metavar="TARGETS.csv", show_default=False,
        help="Target poses `x_<unit>, y_<unit>, z_<unit>` + `psi/theta/phi_<unit>` or qx..qw "
             "(Delta: x, y, z), one per row: single poses or a whole trajectory.")],
    output: OutFile,
    report: Annotated[Path | None, typer.Option(
        help="Calibration report (JSON) with the covariance (default: the one named in the "
             "calibrated file, beside it).", show_default=False)] = None,
    nominal: Annotated[str | None, typer.Option(
        help="The machine file the controller used before (e.g. the nominal one): also "
             "report how far its commands would leave the platform.", show_default=False)]
    = None,
    frame: Annotated[TargetFrame, typer.Option(
        help="base: targets in the calibrated model's base frame (a printer: its frame, z the "
             "height above its bed). instrument: targets in the "
             "measuring instrument's frame, converted with the frames the calibration "
             "estimated (tracker: x, y, z of the target in the tracker's frame, optional column "
             "target 1..K, a platform that rotates keeps its home orientation unless the rows "
             "give one, in the tracker's frame; pose: marker poses in the motion-capture "
             "frame); they land where the instrument will measure them, also along "
             "directions the data cannot fix in the base frame.")]
    = TargetFrame.base,
    instrument: Annotated[str | None, typer.Option(
        metavar="tracker|pose",
        help="With --frame instrument, when the file carries several instrument frames: "
             "which one.", show_default=False)] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")]
    = False,
    columns: ColumnsOpt = None,
) -> None:
    """Joint commands that put the real machine on the targets.

    The calibrated model's inverse kinematics gives the commands; writes the targets with
    q1..qn (the file's units; Stewart: the reading unit) and, per target, the predicted
    residual error of the compensated machine (1 sigma, from the calibration's parameter
    covariance: predicted_position_um, predicted_orientation_urad) and, with --nominal, the
    error the old commands would leave (uncompensated_position_um, ...).

    Example: `pkmcal compensate calibrated.yaml targets.csv -o commands.csv`

    Example: `pkmcal compensate delta_cal.yaml path.csv --nominal examples/delta_default.yaml
    -o arms.csv`
    """
    from ..workflows.compensate import run_compensate
    from ._console import print_summary

    raise typer.Exit(print_summary(run_compensate(machine, targets, output, report, nominal,
                                                  json_output, TargetFrame(frame).value,
                                                  instrument)))


@app.command("export")
def export_command(
    machine: Annotated[str, typer.Argument(
        metavar="CALIBRATED", show_default=False,
        help="The calibrated machine file (from pkmcal calibrate).")],
    to: Annotated[str, typer.Option(
        "--to", metavar="FORMAT", show_default=False,
        help=f"The controller's parameter format: {formats()}.")],
    output: Annotated[str, typer.Option(
        "-o", "--output", metavar="FILE|DIR/", show_default=False,
        help="Output file (written atomically); for the linuxcnc-* formats a directory (a "
             "name ending in '/' or an existing directory) gets a whole LinuxCNC "
             "configuration that starts: machine.ini, machine.hal, kinematics.hal, "
             "drives.hal, tool.tbl, README.md.")],
    nominal: Annotated[str | None, typer.Option(
        help="The machine file the controller's current values come from (e.g. the nominal "
             "one): also report the error they leave on the calibrated machine.",
        show_default=False)] = None,
    workspace: WorkspaceOpt = None,
    seed: Annotated[int, typer.Option(
        min=0, help="Seed of the sampled workspace poses.")] = 0,
) -> None:
    """Write the calibration as the controller's own parameter file (FILE) and a record
    (FILE.json).

    The values are those that minimise the position error over the workspace when the
    controller commands the joints with its own kinematics and the calibrated machine moves;
    the command prints the values written (the controller's units), the error that remains
    (RMS and max over the workspace: what the controller's parameters cannot represent) and,
    with --nominal, the error of the values it had before. linuxcnc-genhexkins (six-strut
    platforms) represents the calibrated model exactly: setp lines of the joints (mm) and a
    HAL scale instance per joint between strut length and the drive's reading.

    Example: `pkmcal export calibrated.yaml --to linuxcnc-genhexkins -o hexapod.hal`

    Example: `pkmcal export calibrated.yaml --to linuxcnc-genhexkins -o hexapod/`

    Example: `pkmcal export cal.yaml --to klipper --nominal printer.yaml -o printer.cfg`
    """
    from ..workflows.export import run_export
    from ._console import print_summary

    raise typer.Exit(print_summary(run_export(machine, to, output, nominal, workspace, seed)))


@app.command("import")
def import_command(
    path: Annotated[Path, typer.Argument(
        metavar="FILE", show_default=False,
        help="The controller's parameter file (e.g. a .hal, printer.cfg or G-code lines); "
             "for the linuxcnc-* formats also a configuration: its INI file or directory "
             "(the joints' zeros from [JOINT_n] HOME_OFFSET).")],
    source_format: Annotated[str, typer.Option(
        "--from", metavar="FORMAT", show_default=False,
        help=f"The file's format: {formats()}.")],
    output: OutFile,
    like: Annotated[str | None, typer.Option(
        help="A machine file to take what the controller's file does not hold from (name, "
             "home, units, joint limits, effector offsets).", show_default=False)] = None,
) -> None:
    """Read a controller's current values back as a pkmcal machine file, to start a
    calibration from what the machine runs today.

    Example: `pkmcal import hexapod.hal --from linuxcnc-genhexkins -o machine.yaml`

    Example: `pkmcal import hexapod/ --from linuxcnc-genhexkins -o machine.yaml`

    Example: `pkmcal import printer.cfg --from klipper --like examples/linear_delta.yaml -o
    printer.yaml`
    """
    from ..workflows.export import run_import
    from ._console import print_summary

    raise typer.Exit(print_summary(run_import(path, source_format, output, like)))


@app.command("report")
def report_command(
    result: Annotated[Path, typer.Argument(
        metavar="RESULT", show_default=False,
        help="A calibration report (the JSON pkmcal calibrate writes beside the calibrated "
             "file) or the calibrated machine file (its report is found beside it).")],
    output: Annotated[Path, typer.Option(
        "-o", "--output", parser=_file_name, metavar="FILE", show_default=False,
        help="The HTML file; its JSON twin is written beside it (same name, .json).")],
) -> None:
    """A self-contained HTML report of a calibration (no network: plots embedded).

    Summary and convergence, identifiability in words with the singular values, residuals
    (histogram of residual / assumed noise against N(0, 1)), before/after accuracy, distance
    ratios (Delta), the measurement frames, the parameter table (nominal, identified, change,
    standard deviation, unit) and the command and versions that produced it.

    Example: `pkmcal report calibrated.json -o report.html`

    Example: `pkmcal calibrate default data.csv -o cal.yaml --report out/` (the same, at once)
    """
    from ..workflows.report import report
    from ._console import print_summary

    raise typer.Exit(print_summary(report(result, output)))


class Trajectory(enum.StrEnum):
    circle = "circle"
    file = "file"


@app.command("errors")
def errors_command(
    machine: Annotated[str, typer.Argument(
        metavar="MACHINE", help="Six-leg machine file (YAML, machine: stewart) or 'cubic' for "
                                "the embedded cubic 6-UPU device of seed 003.",
        show_default=False)],
    output: OutFile,
    trajectory: Annotated[Trajectory | None, typer.Option(
        help="circle (seed 003 case study; default) or file (poses and times from "
             "--trajectory-file).", show_default=False)] = None,
    trajectory_file: Annotated[Path | None, typer.Option(
        "--trajectory-file", dir_okay=False, show_default=False,
        help="Poses over time (CSV): t_s, x_mm, y_mm, z_mm and psi/theta/phi_deg or qx, qy, "
             "qz, qw (no orientation columns: no rotation); accelerations by finite "
             "differences.")] = None,
    radius: Annotated[str | None, typer.Option(
        help="circle: radius [default 100mm].", show_default=False)] = None,
    height: Annotated[str | None, typer.Option(
        help="circle: height z of the platform origin [default 410mm].",
        show_default=False)] = None,
    omega: Annotated[str | None, typer.Option(
        help="circle: angular speed, counter-clockwise from +X [default 10rad/s].",
        show_default=False)] = None,
    samples: Annotated[int | None, typer.Option(
        min=1, max=MAX_SAMPLES,
        help="circle: samples, sample k at 360 k / samples deg [default 360].",
        show_default=False)] = None,
    clearance: Annotated[str, typer.Option(
        help="Radius of the sphere each universal-joint centre can sit in (clearance).")]
    = "10um",
    platform_clearance: Annotated[str | None, typer.Option(
        "--platform-clearance", help="Clearance of the platform joints when it differs from "
                                     "the base joints' (default: --clearance).",
        show_default=False)] = None,
    mass: Annotated[str, typer.Option(help="Platform mass (centre of mass at its origin).")]
    = "4.8kg",
    cutting_force: Annotated[str, typer.Option(
        "--cutting-force", help="Force on the platform at its origin, base frame: fx,fy,fz "
                                "with a unit.")] = "0,0,-500N",
    screw_error: Annotated[str, typer.Option(
        "--screw-error", help="Ball-screw backlash: the leg acts this much longer in tension "
                              "and shorter in compression.")] = "0um",
    force_tol: Annotated[str, typer.Option(
        "--force-tol", help="A leg force within this of zero leaves the side of its joints "
                            "undetermined: the envelope of both sides is reported.")] = "1N",
    plot: Annotated[Path | None, typer.Option(
        file_okay=False, show_default=False,
        help="Directory for plots: leg forces (seed 003 Fig. 6), pose errors (Fig. 7) and "
             "an error map over the workspace slice.")] = None,
    columns: ColumnsOpt = None,
) -> None:
    """Leg forces and pose errors from joint clearance under loads along a trajectory
    (seed 003).

    The loads act at the platform origin: weight, cutting force and inertia. Leg forces are
    tension positive; in tension a leg's joints act 2 x clearance farther apart, in
    compression nearer. Where a leg force is within --force-tol of zero the side is
    undetermined and the envelope of both sides is written. Columns: angle_deg (t_s for a
    file trajectory), f1_N..f6_N, dx_um, dy_um, dz_um, drx_urad, dry_urad, drz_urad, then the
    envelope (dx_min_um, dx_max_um, ...) and the undetermined legs.

    Example: `pkmcal errors cubic --radius 100mm --height 410mm --omega 10rad/s -o errors.csv`

    Example: `pkmcal errors machine.yaml --trajectory-file path.csv --plot plots -o errors.csv`
    """
    from ..workflows.errors import errors
    from ._console import print_summary

    raise typer.Exit(print_summary(errors(
        machine, output, trajectory.value if trajectory else None, trajectory_file, radius,
        height, omega, samples, clearance, platform_clearance, mass, cutting_force,
        screw_error, force_tol, plot)))


@app.command()
def montecarlo(
    machine: MachineArg,
    vary: Annotated[str, typer.Option(
        metavar="VARIABLE=V1,V2,...", show_default=False,
        help="The setting to sweep and its values: noise (measurement noise std, as "
             "--noise), lc-error (error of the assumed constraint-link length; hexaslide), "
             "poses (number of measurements), tolerance (half-width of the random length "
             "deviations; angles and gains in proportion). Values take a unit suffix, once at "
             "the end for all (noise=0.1,1,10um) or each its own; bare numbers are SI.")],
    output: Annotated[Path, typer.Option(
        "-o", "--output", file_okay=False, show_default=False,
        help="Output directory: runs.csv, summary.csv, summary.json, montecarlo.png "
             "(created if missing; each file written atomically).")],
    runs: Annotated[int, typer.Option(min=1, max=MAX_RUNS,
                                      help="Simulated calibrations per value.")] = 20,
    scenario: Annotated[str | None, typer.Option(metavar="SCENARIO",
        help="Measurement scenario (default: the machine type's own, e.g. constraint-link "
             "on a hexaslide, tracker on a delta, pose on a stewart, probe on a "
             "linear_delta).", show_default=False)] = None,
    poses: Annotated[int | None, typer.Option(
        min=1, max=MAX_MEASUREMENTS,
        help="Measurements per calibration when not swept (constraint-link 150, pose 60; "
             "tracker: the 3x3x3 grid, or this many points uniform in its box).",
        show_default=False)] = None,
    noise: Annotated[str | None, typer.Option(
        help="Measurement noise std when not swept: constraint-link encoder noise (default "
             "2um); tracker leica (default) or a length (isotropic); pose: leg readings as a "
             "length (default 2um; poses 20um, 50urad).", show_default=False)] = None,
    lc_error: Annotated[str | None, typer.Option(
        "--lc-error", help="constraint-link: the true link is the machine file's Lc minus "
                           "this; the calibration assumes the file's (default 0).",
        show_default=False)] = None,
    tolerance: Annotated[str | None, typer.Option(
        help="Half-width of the random length deviations of the true machines (default: "
             "the machine type's, e.g. hexaslide 2mm, delta 1mm); implies --deviations "
             "random.",
        show_default=False)] = None,
    deviations: Annotated[Deviations | None, typer.Option(
        help="True machine = MACHINE + deviations: paper-table1, random (a new draw per "
             "run) or none (default: paper-table1 on a hexaslide, random on the others).",
        show_default=False)] = None,
    estimate_lc: Annotated[bool, typer.Option(
        "--estimate-lc", help="constraint-link: estimate Lc too (seed 000 Fig. 6, second "
                              "curve).")] = False,
    seed: Annotated[int, typer.Option(
        min=0, help="Seed: run r at value i draws from SeedSequence(seed, spawn_key=(i, r)); the "
             "same seed gives the same runs.csv whatever --workers or --scheduler.")] = 0,
    workers: Annotated[int | None, typer.Option(
        help="Local worker processes (default: all cores; 1 runs in this process).",
        show_default=False)] = None,
    scheduler: Annotated[str | None, typer.Option(
        metavar="ADDRESS", help="Run on a Dask cluster instead: its scheduler address, e.g. "
                                "tcp://10.0.0.5:8786 (needs pkmcal[distributed]).",
        show_default=False)] = None,
    quiet: Annotated[bool, typer.Option(
        "--quiet", "-q", help="No progress bar (it is also off when stderr is not a "
                              "terminal).")] = False,
) -> None:
    """Monte Carlo of simulated calibrations while one setting varies.

    Each run: true machine = MACHINE + deviations, simulated data of the scenario, the
    default calibration of `pkmcal calibrate`, and the accuracy of the result against the
    truth where the data cannot fix the frames: constraint-link, the workspace pose error
    after aligning the frames the data cannot fix; tracker, held-out tracker points through the
    identified registration; pose, held-out poses through the identified frames and the
    gauge-free parameter error. Every run has a status: ok, not converged, rejected (its
    residuals fail the chi-square test against the simulated noise: a wrong geometry) or
    failed; the others are counted, never averaged. Per value, over the ok runs: mean, 95 %
    confidence interval of the mean, median, MAD spread and 5-95 %. Exits 1 when a value
    has no ok run.

    Example (seed 000 Fig. 5): `pkmcal montecarlo default --vary noise=0.1,0.3,1,3,10um -o fig5`

    Example (Fig. 6): `pkmcal montecarlo default --vary lc-error=1,3,10,30,100um --noise 0
    -o fig6`

    Example: `pkmcal montecarlo examples/delta_default.yaml --vary poses=10,27,60 --runs 50
    --scheduler tcp://127.0.0.1:8786 -o delta-poses`
    """
    from ..workflows.montecarlo import montecarlo as run
    from ._console import print_summary, progress_tasks

    with progress_tasks(quiet) as new:
        summary = run(machine, vary, output, runs=runs, scenario=scenario, poses=poses,
                      noise=noise, lc_error=lc_error, tolerance=tolerance,
                      deviations=deviations.value if deviations else None,
                      estimate_lc=estimate_lc, seed=seed, workers=workers,
                      scheduler=scheduler, progress=new)
    raise typer.Exit(print_summary(summary))


@app.command()
def bench(
    json_output: Annotated[bool, typer.Option("--json", help="Print the results as JSON.")]
    = False,
) -> None:
    """Run the benchmarks (accuracy and speed targets) and print a table.

    Exit code 1 when a benchmark misses its target.

    Example: `pkmcal bench`
    """
    from ..workflows.demo import bench as run
    from ._console import print_summary, progress_tasks

    with progress_tasks() as new:
        summary = run(json_output, progress=new)
    raise typer.Exit(print_summary(summary))


def _one_line(message: str) -> str:
    return " ".join(str(message).split()) if "\n" in str(message) else str(message)


def _fail_interrupted(cause: BaseException) -> None:
    """End as the signal behind ``cause`` (a :class:`Terminated` or a Ctrl-C) ends a run."""
    _fail(*interruption_exit(cause))


def _fail(message: str, code: int = 2) -> None:
    from ._console import error

    error(_one_line(message))
    sys.exit(code)


def _refuse_empty(args: list[str]) -> None:
    """No option or argument of pkmcal takes an empty text: ``--noise ''`` (an unset shell
    variable) would otherwise read as the option's default. The message names the option or
    the argument (``MACHINE``) the empty text stands for."""
    for i, a in enumerate(args):
        if a == "--":
            return
        name = None
        if a.startswith("--") and a.endswith("=") and len(a) > 3:
            name = a[:-1]
        elif a.strip() == "":
            name = _empty_name(args, i)
        if name is not None:
            raise InputError(f"{name}: an empty value (an unset shell variable?); give a value "
                             "or leave the option out" if name.startswith("-") else
                             f"{name}: an empty value (an unset shell variable?)")


def _empty_name(args: list[str], i: int) -> str:
    """What the empty ``args[i]`` stands for: the option it is the value of (``--noise``), or
    the positional argument by its name and place (``MACHINE (argument 1 of pkmcal
    calibrate)``); the bare position when the command is not known."""
    prev = args[i - 1] if i else ""
    fallback = (prev if prev.startswith("-") and prev != "--"
                else f"argument {i + 1}" + (f" (after {prev})" if prev else ""))
    command = next((k for k, a in enumerate(args) if not a.startswith("-")), None)
    if command == i:
        return "COMMAND (the first argument: calibrate, simulate, ...; see pkmcal --help)"
    try:
        import typer.main

        group = typer.main.get_command(_command_app(args))
        cmd = group.commands[args[command]]
    except Exception:       # noqa: BLE001 - an unknown command: the position alone
        return fallback
    options = {o: p for p in cmd.params for o in getattr(p, "opts", ())
               if p.param_type_name == "option"}
    positional = [p for p in cmd.params if p.param_type_name == "argument"]
    k, skip = 0, False
    for a in args[command + 1:i]:
        if skip:
            skip = False
            continue
        option = options.get(a.split("=", 1)[0]) if a.startswith("-") else None
        if option is not None:
            skip = "=" not in a and not getattr(option, "is_flag", False) \
                and not getattr(option, "count", False)
        elif not a.startswith("-") or a == "-":
            k += 1
    if skip:
        return prev
    if not positional:
        return fallback
    param = positional[min(k, len(positional) - 1)]
    meta = str(param.metavar or param.name.upper()).strip("[].")
    import re

    what = re.split(r" \(|`|;|\. |\.$", str(getattr(param, "help", "") or ""))[0].strip()
    what = what[:1].lower() + what[1:] + ", " if what else ""
    return f"{meta} ({what}argument {k + 1} of pkmcal {args[command]})"


def _hoist_quiet(args: list[str]) -> list[str]:
    """``pkmcal calibrate ... -q`` means ``pkmcal -q calibrate ...``: the global --quiet may be
    written after the command too (montecarlo has its own --quiet and keeps it)."""
    end = args.index("--") if "--" in args else len(args)
    command = next((i for i, a in enumerate(args[:end]) if not a.startswith("-")), None)
    if command is None or args[command] == "montecarlo":
        return args
    rest = [a for a in args[command + 1:end] if a not in ("-q", "--quiet")]
    if len(rest) == end - command - 1:
        return args
    return ["--quiet", *args[:command + 1], *rest, *args[end:]]



def _command_app(args: list[str]) -> typer.Typer:
    """The app that runs ``args``: when they name a command, an app holding that command
    alone (typer builds every registered command's parameters from its signature on each
    call, ~20 ms for all of them, while one run needs one); the whole app otherwise (no
    command, an unknown one, ``pkmcal --help``), so help and "No such command" are typer's."""
    end = args.index("--") if "--" in args else len(args)
    word = next((a for a in args[:end] if not a.startswith("-")), None)
    if word is None:
        return app
    from typer.main import get_command_name

    chosen = [info for info in app.registered_commands
              if (info.name or get_command_name(info.callback.__name__)) == word]
    if len(chosen) != 1:
        return app
    import copy

    one = copy.copy(app)            # the same settings, callback and commands' objects
    one.registered_commands = chosen
    return one


def _run(args: list[str], final: bool = False) -> None:
    """Run the command inside one output set: its files appear together when it succeeds
    (or where it commits them itself), and none of them on an error or an interrupt. A
    usage error (unknown option, a value out of range) is one line naming the option."""
    from typer import Abort
    from typer._click.exceptions import ClickException, NoArgsIsHelpError

    from ..io.atomic import OutputSet

    with OutputSet(final=final):
        try:
            code = _command_app(args)(args=args, prog_name="pkmcal", standalone_mode=False)
        except NoArgsIsHelpError as exc:
            exc.show()
            raise SystemExit(exc.exit_code) from None
        except ClickException as exc:
            where = getattr(getattr(exc, "ctx", None), "command_path", None) or "pkmcal"
            raise InputError(f"{_one_line(exc.format_message())} (see {where} --help)",
                             getattr(exc, "exit_code", 2)) from None
        except Abort:
            raise KeyboardInterrupt from None
        finally:
            _reset_column_map()
        if isinstance(code, int) and code != 0:
            raise SystemExit(code)


def main(argv: list[str] | None = None, exiting: bool = False) -> None:
    """Run ``pkmcal`` with ``argv`` (default: the command line).

    Parameters
    ----------
    argv : list of str, optional
        The arguments after ``pkmcal``.
    exiting : bool, optional
        The process ends after this call (the console script): once the outputs are
        committed, signals are held back until exit, so they cannot fail a finished run.
    """
    import warnings

    # Batched small matrices: threaded BLAS costs ~10x in start-up and synchronisation.
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    args = list(sys.argv[1:] if argv is None else argv)
    if not os.environ.get("PKMCAL_DEBUG"):
        # numpy's floating-point warnings (overflow, invalid value) and library warnings are
        # for developers (PKMCAL_DEBUG=1 shows them): the user's numbers are checked up front
        # against absolute limits and the machine's scale, so none should arise, and pkmcal's
        # own warnings go through the console
        warnings.simplefilter("ignore")
    forget_signals()
    previous = handle_signals()
    try:
        _main(args, exiting)
    finally:
        if not exiting:     # called from Python: the caller's handlers back, the signal gone
            restore_signals(previous)
            forget_signals()


def _main(args: list[str], exiting: bool) -> None:
    """:func:`main` under pkmcal's signal handlers: every ending is one line and an exit code
    (0 on success, 1 for a bug, 2 for bad input, 130 or 128 + n for a signal)."""
    try:
        from ..report.provenance import run_date

        run_date()      # a malformed SOURCE_DATE_EPOCH is refused before any import reads it
        _refuse_empty(args)
        args = _hoist_quiet(args)
        _run(args, final=exiting)
    except (KeyboardInterrupt, Terminated) as exc:
        _fail_interrupted(exc)
    except SystemExit as exc:
        if exc.code == 130:     # typer turns Ctrl-C into exit code 130, silently
            _fail_interrupted(KeyboardInterrupt())
        raise
    except Exception as exc:
        # a signal can surface as another exception: an ImportError it broke, or whatever an
        # extension module raised after swallowing the signal's own - the run was interrupted
        cause = interruption(exc)
        if cause is not None:
            _fail_interrupted(cause)
        _fail_exception(exc)


def _fail_exception(exc: Exception) -> None:
    """End the run on ``exc``: exit 2 with its message for what the user can mend, 1 with one
    line for a bug (the traceback with PKMCAL_DEBUG=1)."""
    if isinstance(exc, InputError):
        code = exc.args[1] if len(exc.args) > 1 and isinstance(exc.args[1], int) else 2
        _fail(str(exc.args[0]) if len(exc.args) > 1 else str(exc), code)
    if isinstance(exc, ConvergenceError):
        _fail(str(exc))
    if isinstance(exc, FileNotFoundError):
        _fail(f"{path_text(exc.filename)}: file not found" if exc.filename else str(exc))
    if isinstance(exc, OSError):
        if exc.filename:
            _fail(f"{path_text(exc.filename)}: {exc.strerror or exc}")
        _fail(str(exc))
    if os.environ.get("PKMCAL_DEBUG"):
        raise exc
    _fail(f"internal error ({type(exc).__name__}: {exc}); please report it with the "
          "command line (PKMCAL_DEBUG=1 shows the traceback)", 1)
