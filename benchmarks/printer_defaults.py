"""The printer defaults (``--parameters auto``, build tolerances as a prior) against the
Cramér-Rao bound of the family the errors lie in (issue 35, "Done when").

The printer is :mod:`benchmarks.printer`'s (118 mm radius, 232 mm arms, towers off Klipper's
angles and leaning a few hundredths of a degree: all known, in the nominal). Its true errors lie
in **Klipper's nine parameters plus a bed tilt**: endstops and radius off by up to 1 mm, the
angles of towers 1 and 2 by up to 0.3 deg, each arm by up to 1 mm (uniform), the bed tilted
by up to 1 mrad in a random direction. 61 probe points (the centre and 4 rings), 10 um trigger
noise. The machine carries the default build tolerances
(:data:`~pkmcal.machines.linear_delta.LinearDelta.DEFAULT_TOLERANCES`).

For each true printer (``seed``) and ``runs`` noise draws the script calibrates with the
defaults (:func:`pkmcal.calibration.calibrate`, no ``--parameters``: ``auto``) and with the
fixed choices ``full`` and ``klipper-basic``, and reports the RMS over runs and 40 held-out
points of the height each predicts where the true nozzle touches the true bed (0), against
the Cramér-Rao prediction of the family (Klipper's nine + the bed's tilt, maximum likelihood,
at the truth): ``sqrt(mean_k J_h,k C J_h,k^T)``.

Usage (from the repository root)::

    .venv/bin/python benchmarks/printer_defaults.py --seeds 5 --runs 40

``tests/test_printer_defaults.py`` runs a small case (and the full size as a ``study``).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from pkmcal.calibration import calibrate  # noqa: E402
from pkmcal.instruments import InstrumentData, IsotropicNoise, ProbeModel  # noqa: E402
from pkmcal.instruments.probe import PROBE_SIGMA, ProbeProblem  # noqa: E402
from pkmcal.instruments.registry import instrument  # noqa: E402
from pkmcal.instruments.simulate import probe_trigger  # noqa: E402
from pkmcal.planning import standard_plan  # noqa: E402

HERE = Path(__file__).resolve().parent
N_POINTS = 61
N_HELD = 40
#: the true errors: uniform within (m, rad); the bed's tilt size uniform in [0, BED_TILT]
ERRORS = {"endstop": 1e-3, "delta_radius": 1e-3, "angle": float(np.deg2rad(0.3)),
          "arm": 1e-3}
BED_TILT = 1e-3
FAMILY = "klipper"
#: the fixed choices compared with the defaults
OTHERS = ("full", "klipper-basic")


def _printer_module():
    spec = importlib.util.spec_from_file_location("printer_bench", HERE / "printer.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, module)
    spec.loader.exec_module(module)
    return module


def nominal_printer():
    """The benchmark printer with the default build tolerances as a prior."""
    return _printer_module().printer().with_tolerances("default")


class Case:
    """One true printer: errors in Klipper's nine and a bed tilt; plan, held-out points, the
    family's bound."""

    def __init__(self, seed: int, sigma: float = PROBE_SIGMA):
        rng = np.random.default_rng(seed)
        self.sigma = sigma
        self.nominal = nominal_printer()
        p = self.nominal.parameters
        du = np.zeros(len(p))
        for i in range(3):
            du[p.index(f"tower{i + 1}.endstop")] = rng.uniform(-1, 1) * ERRORS["endstop"]
            du[p.index(f"tower{i + 1}.arm_trim")] = rng.uniform(-1, 1) * ERRORS["arm"]
        du[p.index("delta_radius")] = rng.uniform(-1, 1) * ERRORS["delta_radius"]
        for i in range(2):
            du[p.index(f"tower{i + 1}.angle")] = rng.uniform(-1, 1) * ERRORS["angle"]
        self.true = self.nominal.with_parameters(self.nominal.u + du).with_tolerances("none")
        size, direction = rng.uniform(0, BED_TILT), rng.uniform(0, 2 * np.pi)
        self.bed = np.array([0.0, size * np.cos(direction), size * np.sin(direction)])
        plan = standard_plan(self.nominal, "probe", N_POINTS)
        self.P, self.R = plan.P, plan.R
        P, R, _ = instrument("probe").candidates(self.nominal, N_HELD, rng)
        self.q_held, _ = probe_trigger(self.true, self.nominal, P, R, self.bed,
                                       np.zeros(N_HELD))
        self.noise = IsotropicNoise(sigma)

    def data(self, rng=None) -> InstrumentData:
        eps = np.zeros(len(self.P)) if rng is None else \
            self.sigma * rng.standard_normal(len(self.P))
        q, _ = probe_trigger(self.true, self.nominal, self.P, self.R, self.bed, eps)
        return InstrumentData("probe", q, np.zeros((len(q), 1)), source="probe.csv")

    def _problem(self, q, h):
        model = ProbeModel(fixed=("bed.z",))
        model.parameters = model.parameters.with_values(self.bed)
        machine = self.true.with_parameter_set(FAMILY)
        return ProbeProblem(machine, InstrumentData("probe", q, h), model, self.noise)

    def bound_rms(self) -> float:
        """The family's Cramér-Rao prediction of the held-out height RMS, m."""
        def jac(problem):
            _, J, _ = problem.evaluate(problem.initial_state())
            free = problem.parameters.free
            return (J[..., free] * problem.scales[free]).reshape(-1, int(free.sum()))

        exact = self.data(None)
        J = jac(self._problem(exact.q, exact.values))
        Jh = jac(self._problem(self.q_held, np.zeros((N_HELD, 1)))) * self.sigma
        _, s, Vt = np.linalg.svd(J, full_matrices=False)
        rank = int(np.sum(s > 1e-10 * s[0]))
        C = (Vt[:rank].T / s[:rank] ** 2) @ Vt[:rank]
        return float(np.sqrt(np.trace(Jh @ C @ Jh.T) / N_HELD))

    def held_heights(self, calibration) -> np.ndarray:
        result = calibration.result
        return result.problem.predict(result.state, self.q_held)[:, 0]


def run_case(seed: int, runs: int, others=OTHERS) -> dict:
    """``runs`` noisy calibrations of one true printer: held-out RMS per choice, the bound,
    and the models ``auto`` chose."""
    case = Case(seed)
    rng = np.random.default_rng(1000 + seed)
    heights = {"auto": [], **{o: [] for o in others}}
    chosen = {}
    for _ in range(runs):
        data = case.data(rng)
        cal = calibrate(case.nominal, data)
        heights["auto"].append(case.held_heights(cal))
        name = cal.report.get("parameter_set", {}).get("name", "?")
        chosen[name] = chosen.get(name, 0) + 1
        for o in others:
            heights[o].append(case.held_heights(calibrate(case.nominal, data, parameters=o)))
    crb = case.bound_rms()
    rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in heights.items()}
    return {"seed": seed, "runs": runs, "crb_um": crb * 1e6,
            "rms_um": {k: v * 1e6 for k, v in rms.items()},
            "ratio": {k: v / crb for k, v in rms.items()}, "chosen": chosen}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    out = [run_case(seed, args.runs) for seed in range(args.seeds)]
    for row in out:
        print(f"seed {row['seed']}: bound {row['crb_um']:.2f} um; "
              + ", ".join(f"{k} {v:.3f}x" for k, v in row["ratio"].items())
              + f"; chosen {row['chosen']}")
    pooled = {k: float(np.sqrt(np.mean([r["ratio"][k] ** 2 for r in out])))
              for k in out[0]["ratio"]}
    print("pooled (RMS of the ratios): " + ", ".join(f"{k} {v:.3f}x" for k, v in pooled.items()))
    if args.json:
        Path(args.json).write_text(json.dumps({"cases": out, "pooled": pooled}, indent=1))


if __name__ == "__main__":
    main()
