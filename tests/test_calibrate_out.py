"""The calibration scripts' output (scripts/_fit_output.py): without --out calibrate_map_verdict.py writes
results/map_verdict_model.json in the working directory; an --out inside the package (the shipped coefficients) is
refused without --force, before anything runs, by it and calibrate_verdict.py, and the shipped file is left as it
was."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import _fit_output  # noqa: E402
import calibrate_map_verdict as cmv  # noqa: E402
import calibrate_verdict as cv  # noqa: E402

from deepbbs_ros.core import calibrated, map_verdict  # noqa: E402


def _rows(path: Path) -> Path:
    """Kept rows (as --dump writes them) of two separable classes: right poses have high features, wrong low."""
    rng = np.random.default_rng(0)
    y = np.repeat([1, 0], 20)
    x = np.clip(np.where(y[:, None] == 1, 0.8, 0.2) + rng.normal(0, 0.05, (40, len(map_verdict.names()))), 0, 1)
    np.savez(path, x=x, y=y, kind=np.repeat(["near", "moved"], 20), rig=np.zeros(40, int))
    return path


def test_default_output_is_in_the_working_directory(tmp_path, monkeypatch):
    rows = _rows(tmp_path / "rows.npz")
    monkeypatch.chdir(tmp_path)
    before = map_verdict.DEFAULT_PATH.read_bytes()
    assert cmv.main(["--rows", str(rows)]) == 0
    doc = json.loads((tmp_path / "results" / "map_verdict_model.json").read_text())
    assert doc["features"] == list(map_verdict.names()) and len(doc["coef"]) == len(doc["features"])
    assert map_verdict.DEFAULT_PATH.read_bytes() == before


@pytest.mark.parametrize("script, shipped", [(cmv, map_verdict.DEFAULT_PATH), (cv, calibrated.DEFAULT_PATH)])
def test_the_shipped_file_is_refused_without_force(tmp_path, capsys, script, shipped):
    rows = _rows(tmp_path / "rows.npz")
    before = shipped.read_bytes()
    with pytest.raises(SystemExit) as e:
        script.main(["--rows", str(rows), "--out", str(shipped)])
    assert e.value.code == 2 and "--force" in capsys.readouterr().err
    assert shipped.read_bytes() == before
    assert _fit_output.shipped(shipped) and not _fit_output.shipped(tmp_path / "m.json")
