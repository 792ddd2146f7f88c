"""Several instruments in one fit (issue 14.4): the joint problem of points and distances on
geometries that are not the examples, its covariance against the summed information, what
each file adds, ``calibrate`` with several files (library and command line), and
``--parameters``."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from clitools import assert_input_error, run  # noqa: E402
from pkmcal.calibration.run import calibrate  # noqa: E402
from pkmcal.errors import InputError  # noqa: E402
from pkmcal.instruments import (  # noqa: E402
    DistancesModel,
    InstrumentProblem,
    IsotropicNoise,
    PointsModel,
)
from pkmcal.instruments.joint import JointProblem, fit_joint  # noqa: E402
from pkmcal.instruments.simulate import (  # noqa: E402
    circle_plan,
    sample_workspace_poses,
    simulate_instrument,
)
from pkmcal.instruments.tracker import TrackerNoise
from pkmcal.io import write_instrument  # noqa: E402
from pkmcal.machines.deviations import random_deviations
from test_instruments import bench  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _points_truth(nominal, n_targets):
    """The benchmark's tracker (1.9 m away, turned) and targets, as a model state."""
    model = PointsModel(n_targets, nominal.tracker_target())
    values = np.array(model.parameters.values, float)
    values[3:6] = bench.TRACKER_T
    if nominal.tracker_target() is None:
        values[6:] = bench.TARGETS[:n_targets].ravel()
    model.parameters = model.parameters.with_values(values)
    model.rotation_starts = [bench.TRACKER_R]
    return model, model.initial()


def _distances_truth(nominal, setups):
    model = DistancesModel(len(setups))
    truth = model.initial()
    for g, (p, b) in enumerate(setups):
        truth.values[model._ip[g]] = p
        truth.values[model._ib[g]] = b
    return model, truth


def _case(name, seed=1, n_points=40, n_lengths=60, circle=False, noise=False):
    """A true machine (nominal + deviations), tracker points and ballbar lengths of it."""
    rng = np.random.default_rng(seed)
    nominal = bench.MACHINES[name]()
    true = nominal.with_parameters(nominal.u + random_deviations(nominal, rng))
    n_targets = 1 if nominal.tracker_target() is not None else 2
    pmodel, ptruth = _points_truth(nominal, n_targets)
    P, R = sample_workspace_poses(nominal, n_points, rng)
    pts = simulate_instrument(true, nominal, pmodel, ptruth, P, R, np.arange(n_points)
                              % n_targets, TrackerNoise() if noise else None, rng)
    pts.source = "pts.csv"
    if circle:                                   # one ISO 230-4 circle: one mounting
        setups = [(nominal.home[0] + bench.PIVOTS[0], bench.BALLS[0])]
        P2, R2, g2 = circle_plan(nominal, n_lengths, setups)
    else:
        setups = [(nominal.home[0] + bench.PIVOTS[g], bench.BALLS[g]) for g in range(2)]
        P2, R2 = sample_workspace_poses(nominal, n_lengths, rng)
        g2 = np.arange(n_lengths) % 2
    dmodel, dtruth = _distances_truth(nominal, setups)
    bar = simulate_instrument(true, nominal, dmodel, dtruth, P2, R2, g2,
                              IsotropicNoise(1e-6) if noise else None, rng)
    bar.source = "bar.csv"
    parts = [(pts, PointsModel(n_targets, nominal.tracker_target()), TrackerNoise()),
             (bar, DistancesModel(len(setups)), IsotropicNoise(1e-6))]
    return nominal, true, parts, [(pmodel, ptruth), (dmodel, dtruth)], rng


@pytest.mark.parametrize("name", ["hexaslide", "stewart"])
def test_points_and_distances_recover_the_truth_noise_free(name):
    """Noise-free points + distances: one joint fit predicts both instruments' readings at
    held-out joint readings as the truth does, to 1e-9 of the machine's size (gauge-free: an
    unidentifiable change changes no prediction), and the frames are named with the file of
    each absorber."""
    nominal, true, parts, truths, rng = _case(name)
    result = fit_joint(nominal, parts)
    assert result.success and result.weak == 0
    problem = result.problem
    assert isinstance(problem, JointProblem)
    names = problem.parameters.names
    assert "pts.csv:tracker.x" in names and "bar.csv:setup1.pivot.x" in names
    assert result.residuals.shape == (3 * len(parts[0][0]) + len(parts[1][0]), 1)
    P, R = sample_workspace_poses(nominal, 25, rng)
    q = nominal.ik(P, R)
    fk = true.fk(q, start=(P, R))
    L = nominal.characteristic_length()
    for i, (model, truth) in enumerate(truths):
        group = np.zeros(len(q), int)
        expected = model.predict(truth, fk.P, fk.R, group)
        got = problem.parts[i].predict(problem.part_state(result.state, i), q, group)
        assert np.abs(got - expected).max() <= 1e-9 * L, (i, np.abs(got - expected).max())
    words = " ".join(d.description for d in result.unidentifiable)
    assert "the tracker frame of pts.csv" in words
    assert "the ballbar's pivot on the base of bar.csv" in words


def _information(problem, state, columns, n):
    """Whitened information matrix ``J^T J`` of a single-file problem, in joint columns."""
    _, J, _ = problem.evaluate(state)
    J = J.reshape(-1, J.shape[-1])
    full = np.zeros((len(J), n))
    full[:, columns] = J
    return full.T @ full


def test_joint_covariance_is_the_inverse_of_the_summed_information():
    """Cramér-Rao: the joint fit's covariance (assumed noise, absolute) equals the
    (pseudo-)inverse of the sum of the two single problems' information matrices, in the
    estimator's scaled coordinates over the free parameters."""
    nominal, _, parts, _, _ = _case("hexaslide", seed=4, noise=True)
    result = fit_joint(nominal, parts, absolute_sigma=True)
    assert result.success and result.weak == 0
    problem = result.problem
    n = len(problem.parameters)
    info = np.zeros((n, n))
    for i, part in enumerate(problem.parts):
        single = InstrumentProblem(nominal, part.data, part.model, part.noise)
        info += _information(single, problem.part_state(result.state, i), problem.columns(i),
                             n)
    free = problem.parameters.free
    S = problem.scales[free]
    scaled_info = info[np.ix_(free, free)] * np.outer(S, S)
    expected = np.linalg.pinv(scaled_info, rcond=1e-10, hermitian=True)
    got = result.covariance[np.ix_(free, free)] / np.outer(S, S)
    assert np.abs(got - expected).max() <= 1e-6 * np.abs(expected).max()
    # and the per-file view: the joint std never exceeds a file's alone
    c = result.sections["joint"].contributions
    for i in range(2):
        ok = np.isfinite(c.alone_std[i]) & np.isfinite(c.joint_std)
        assert np.all(c.joint_std[ok] <= c.alone_std[i][ok] * (1 + 1e-9))


def test_a_ballbar_circle_alone_leaves_directions_the_points_fix(tmp_path):
    """Delta: one ballbar circle leaves machine directions free that tracker points fix; the
    contributions say so (ranks alone and together, the directions pts.csv adds, the
    parameters 'not fixed' from the circle alone), and so does the report of ``calibrate``
    with the two files."""
    nominal, _, parts, _, _ = _case("delta", circle=True, n_lengths=36, n_points=30)
    result = fit_joint(nominal, parts)
    c = result.sections["joint"].contributions
    pts_alone, circle_alone = c.alone_identifiable
    assert circle_alone < pts_alone == c.joint_identifiable == 15
    assert len(c.added[0]) == c.joint_identifiable - circle_alone      # pts.csv fixes them
    assert c.added[1] == []                                            # the circle: nothing
    assert np.isnan(c.alone_std[1]).sum() > np.isnan(c.joint_std).sum()
    lines = "\n".join(c.lines())
    assert "pts.csv fixes what the other file(s) leave free" in lines
    assert "not fixed from bar.csv alone" in lines

    for data, _, _ in parts:
        write_instrument(tmp_path / data.source, data, nominal)
    cal = calibrate(nominal, [tmp_path / "pts.csv", tmp_path / "bar.csv"])
    report = cal.report
    assert cal.kind == "joint" and report["measurement"] == "joint"
    files = {f["label"]: f for f in report["files"]}
    assert set(files) == {"pts.csv", "bar.csv"}
    contributions = {f["file"]: f for f in report["contributions"]["files"]}
    assert contributions["bar.csv"]["identifiable_alone"] == circle_alone
    assert contributions["pts.csv"]["fixes_with_the_others"]
    assert report["contributions"]["joint_identifiable"] == 15
    for f in files.values():
        assert f["residuals"]["rms_um"] < 1e-3 < f["residuals"]["before_rms_um"]
    assert len(cal.setups["distance"].mountings) == 1
    assert not hasattr(cal.calibrated, "ballbar_setups")


def test_one_file_in_a_list_is_the_single_file_calibration(tmp_path):
    """``calibrate(machine, [path])`` is ``calibrate(machine, path)``: same kind, same
    numbers."""
    nominal, _, parts, _, _ = _case("delta", n_lengths=48)
    write_instrument(tmp_path / "bar.csv", parts[1][0], nominal)
    one = calibrate(nominal, tmp_path / "bar.csv")
    listed = calibrate(nominal, [tmp_path / "bar.csv"])
    assert one.kind == listed.kind == "distance"
    np.testing.assert_array_equal(one.result.x, listed.result.x)
    assert "files" not in listed.report


class _WithSets(type(bench.MACHINES["delta"]())):
    """A Delta with named parameter sets (as a linear Delta's firmware sets)."""

    PARAMETER_SETS = {"lengths": type("S", (), {"free": ("leg1.dl1", "leg2.dl1",
                                                         "leg3.dl1")})()}

    def parameter_set(self, name):
        from pkmcal.parameters import ParameterSet

        p = self.parameters
        if name == "full":
            return ParameterSet(p.names, p.kinds, p.values, np.zeros(len(p), bool))
        if name != "lengths":
            raise InputError(f"unknown parameter set {name!r}")
        free = {"leg1.dl1", "leg2.dl1", "leg3.dl1"}
        return ParameterSet(p.names, p.kinds, p.values, [n not in free for n in p.names])


def test_parameters_option_fixes_what_the_set_does_not_free(tmp_path):
    """``parameters=NAME``: the set's fixed flags replace the machine's; the report records
    the set; an unknown name lists the machine's sets; a machine with no named sets says
    which machines have them."""
    base = bench.MACHINES["delta"]()
    machine = _WithSets.__new__(_WithSets)
    machine.__dict__.update(base.__dict__)
    nominal, _, parts, _, _ = _case("delta", n_lengths=48)
    write_instrument(tmp_path / "bar.csv", parts[1][0], nominal)
    write_instrument(tmp_path / "pts.csv", parts[0][0], nominal)
    for data in (tmp_path / "bar.csv", [tmp_path / "pts.csv", tmp_path / "bar.csv"]):
        cal = calibrate(machine, data, parameters="lengths")
        assert cal.report["parameter_set"]["name"] == "lengths"
        assert cal.report["parameter_set"]["free"] == ["leg1.dl1", "leg2.dl1", "leg3.dl1"]
        assert cal.metadata["parameter_set"] == "lengths"
        changed = {p["name"] for p in cal.params if ":" not in p["name"]
                   and p["name"] in machine.parameters.names and p["change"] != 0}
        assert changed <= {"leg1.dl1", "leg2.dl1", "leg3.dl1"} and changed
    with pytest.raises(InputError, match="--parameters marlin: .*its sets: full, lengths"):
        calibrate(machine, tmp_path / "bar.csv", parameters="marlin")
    with pytest.raises(InputError, match="--parameters klipper: a delta has no named "
                                         "parameter sets besides full .*_?machines with them"):
        calibrate(nominal, tmp_path / "bar.csv", parameters="klipper")


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """Tracker points and ballbar lengths of one true Hexa Slide (the example file), and a
    pose file of the example Stewart."""
    work = tmp_path_factory.mktemp("joint")
    hexa = EXAMPLES / "hexaslide_default.yaml"
    for args in (("--scenario", "points", "--targets", "2", "-o", "pts.csv"),
                 ("--scenario", "distance", "--setups", "3", "-o", "bar.csv")):
        proc = run("simulate", hexa, "--seed", "3", *args, cwd=work)
        assert proc.returncode == 0, proc.stderr
    stewart = EXAMPLES / "cubic_6upu.yaml"
    for args in (("--scenario", "pose", "--poses", "30", "-o", "poses.csv"),
                 ("--scenario", "distance", "-o", "sbar.csv")):
        proc = run("simulate", stewart, "--seed", "3", *args, cwd=work)
        assert proc.returncode == 0, proc.stderr
    (work / "junk.csv").write_text("a,b\n1,2\n")
    return work


def test_command_line_with_two_files(work):
    """``pkmcal calibrate MACHINE pts.csv bar.csv``: per-file residuals before and after,
    what each file adds, the frames named with their file, per-file hold-out, both
    instruments in the calibrated file; the JSON report has every file."""
    hexa = EXAMPLES / "hexaslide_default.yaml"
    proc = run("calibrate", hexa, "pts.csv", "bar.csv", "--noise", "bar.csv=1um",
               "--holdout", "0.2", "-o", "cal.yaml", cwd=work)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = proc.stdout
    for words in ("2 files fitted together", "each file adds", "alone: 42 from pts.csv",
                  "absorbed by the tracker frame of pts.csv", "held-out",
                  "tracker (frame and targets) from pts.csv", "ballbar setups 1..3 from "
                  "bar.csv"):
        assert words in " ".join(out.split()), (words, out)
    report = json.loads((work / "cal.json").read_text())
    assert report["data_files"] == ["pts.csv", "bar.csv"]
    assert [f["measurement"] for f in report["files"]] == ["tracker", "distance"]
    assert all("validation" in f for f in report["files"])
    assert "chi2" in report["acceptance"]["residuals"]         # the chi-square is tested
    text = (work / "cal.yaml").read_text()
    assert "tracker:" in text and "ballbar:" in text and "method: joint" in text


@pytest.mark.parametrize("args,words", [
    (("pts.csv", "junk.csv"), ("junk.csv", "cannot tell the measurement type")),
    (("pts.csv", "bar.csv", "--noise", "2um"), ("FILE=VALUE",)),
    (("pts.csv", "bar.csv", "--noise", "nope.csv=2um"), ("nope.csv is none of the data",)),
    (("pts.csv", "bar.csv", "--noise", "bar.csv="), ("--noise bar.csv=", "no value after")),
    (("pts.csv", "bar.csv", "--noise", "=2um"), ("--noise =2um", "none of the data files")),
    (("pts.csv", "bar.csv", "--noise", "2um"), ("levels of files without one are estimated",)),
    (("bar.csv", "--noise", "bar.csv="), ("--noise bar.csv=", "no value after")),
    (("pts.csv", "--pose-noise", "20um,50urad", "--pose-noise", "30um,60urad"),
     ("--pose-noise", "given more than once")),
    (("pts.csv", "bar.csv", "--two-step"), ("--two-step", "several data files")),
    (("pts.csv", "pts.csv"), ("given twice",)),
    (("bar.csv", "--parameters", "klipper"), ("--parameters klipper", "no named parameter "
                                                                       "sets")),
])
def test_command_line_refusals(work, args, words):
    """Bad input with several files: exit 2, one line naming the problem."""
    proc = run("calibrate", EXAMPLES / "hexaslide_default.yaml", *args, "-o", "x.yaml",
               cwd=work)
    assert_input_error(proc, *words)
    assert not (work / "x.yaml").exists()


def test_kinds_that_cannot_combine_are_refused(work):
    """Full poses (a pose per measurement) do not combine: exit 2 naming the kinds that do."""
    proc = run("calibrate", EXAMPLES / "cubic_6upu.yaml", "poses.csv", "sbar.csv", "-o",
               "x.yaml", cwd=work)
    assert_input_error(proc, "poses.csv", "cannot be combined", "distance", "tracker")


def test_file_noise_of_two_files_of_one_name_holds_only_the_one_named():
    """``--noise a.csv=1um`` with ``a.csv`` and ``sub/a.csv``: the file as given is the first,
    the second is ``sub/a.csv`` or its label ``a.csv#2``; one value never holds both (the file
    name alone matched every file of that name)."""
    from pkmcal.calibration.noise_args import noise_of as _noise_of
    from pkmcal.calibration.noise_args import noise_per_file_arg

    sources = ["a.csv", "sub/a.csv"]
    given = noise_per_file_arg(["a.csv=1um"], sources)
    assert [_noise_of(given, sources, i) for i in range(2)] == ["1um", None]
    for name in ("a.csv#2", "sub/a.csv"):
        given = noise_per_file_arg([f"{name}=2um"], sources)
        assert [_noise_of(given, sources, i) for i in range(2)] == [None, "2um"]
    # a mapping by index or by label from Python
    assert [_noise_of({1: "3um"}, sources, i) for i in range(2)] == [None, "3um"]
    assert [_noise_of({"a.csv#2": "3um"}, sources, i) for i in range(2)] == [None, "3um"]
    # the same resolver as the command line's: an absolute path names the file given
    # relatively, and a key naming no file is refused (it would leave a level estimated)
    from pathlib import Path

    absolute = str(Path("sub/a.csv").resolve())
    assert [_noise_of({absolute: "4um"}, sources, i) for i in range(2)] == [None, "4um"]
    for key in ("b.csv", 2, -1):
        with pytest.raises(InputError, match="none of the data files"):
            _noise_of({key: "1um"}, sources, 0)
    assert [_noise_of({np.int64(1): "5um"}, sources, i) for i in range(2)] == [None, "5um"]
    with pytest.raises(InputError, match="name the same data file"):
        _noise_of({0: "1um", "a.csv": "2um"}, sources, 1)


def test_a_file_named_by_its_absolute_path_is_the_file(work):
    """``--noise /abs/path/bar.csv=VALUE`` names ``bar.csv`` given relatively: held."""
    proc = run("calibrate", EXAMPLES / "hexaslide_default.yaml", "pts.csv", "bar.csv",
               "--noise", f"{(work / 'bar.csv').resolve()}=2um", "-o", "abs.yaml", "-q",
               cwd=work)
    assert proc.returncode == 0, proc.stderr
    groups = json.loads((work / "abs.json").read_text())["noise_model"]["groups"]
    status = {g["key"]: g["status"] for g in groups}
    assert status["bar.csv:distances"] == "held"
    assert all(v != "held" for k, v in status.items() if k.startswith("pts.csv"))
