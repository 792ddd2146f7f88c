"""Several of a printer's sessions pooled (issue 35): each file's noise level its own
(variance components, not the relative weights Klipper gives one run), and ``--parameters
auto`` judged by leaving each session out in turn. Aieie78's V400 backups
(``../shared/data/printers/klipper_saved``, points only); skipped without ``../shared``."""

from __future__ import annotations

import warnings
from pathlib import Path
from types import SimpleNamespace

import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "printers"
RUNS = [SHARED / "klipper_saved" / f"v400-aieie78-run{i}.cfg" for i in range(1, 6)]
needs_shared = pytest.mark.skipif(not SHARED.is_dir(), reason=f"{SHARED} not found: the real "
                                  "printers' files stay outside the project (../shared)")


def pooled_points():
    from pkmcal.export import controller_format
    from pkmcal.io.klipper_data import klipper_sessions

    fmt = controller_format("klipper")
    machine = fmt.to_machine(fmt.parse(RUNS[-1].read_text(), str(RUNS[-1])))
    data = [d for d in klipper_sessions(RUNS, machine).data
            if getattr(d, "mesh", None) is None]
    return machine, data


@needs_shared
def test_pooled_sessions_estimate_each_files_noise_level():
    """Two sessions' DELTA_ANALYZE distances that do not fit the machine the heights of three
    sessions show (residuals of hundreds of um) were held at Klipper's weight against the
    heights (18.5 um) and bent the fit; pooled, each file's level is estimated from its own
    residuals, the distances are down-weighted and the noise report names them."""
    from pkmcal.calibration.run import calibrate

    machine, data = pooled_points()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c = calibrate(machine, data, parameters="klipper")
    groups = {g["key"]: g for g in c.report["noise_model"]["groups"]}
    distances = [g for k, g in groups.items() if "distances" in k]
    assert len(distances) == 2
    for g in distances:
        assert g["status"] == "estimated", g
        assert g["sigma"] > 10 * g["assumed"], g        # named: 30x the level assumed
    texts = [f["noise"] for f in c.report["files"] if "distances" in f["label"]]
    assert all("estimated from its own residuals" in t for t in texts), texts
    heights = [f["residuals"]["rms_um"] for f in c.report["files"] if "heights" in f["label"]]
    assert max(heights) < 20.0, heights         # the heights fitted to their noise


def test_leaving_out_the_reference_session_makes_the_newest_remaining_one_it():
    from pkmcal.calibration.model_choice import _without_session

    items = [SimpleNamespace(session=s, source=str(i)) for i, s in
             enumerate(["a", "b", None, None])]
    sessions = [d.session for d in items]
    kept, out = _without_session(items, sessions, None)
    assert [d.source for d in out] == ["2", "3"]
    assert [d.session for d in kept] == ["a", None]         # b is the reference now
    assert items[1].session == "b"                          # the caller's data untouched
    kept, out = _without_session(items, sessions, "a")
    assert [d.session for d in kept] == ["b", None, None] and [d.source for d in out] == ["0"]


@needs_shared
def test_auto_judges_pooled_sessions_by_leaving_each_out():
    """--parameters auto on three sessions: each session predicted by the others' fit decides
    (PRESS over rows preferred the per-tower model, which predicts the later sessions worse);
    a session without which a candidate is another model (the reference: its distances fix
    Klipper's arms) is not one of the folds, and the report says so."""
    from pkmcal.calibration.run import calibrate

    machine, data = pooled_points()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c = calibrate(machine, data)
    choice = c.report["model_choice"]
    assert "leave one session out" in choice["criterion"]
    scores = [s["loo_rms_over_noise"] for s in choice["candidates"]]
    assert all(s is not None for s in scores)
    assert scores[choice["chosen"]] == min(scores)
    chosen = choice["candidates"][choice["chosen"]]
    assert "not the reference" in chosen["note"]
    assert c.report["parameter_set"]["name"] == chosen["parameters"] == "klipper"
