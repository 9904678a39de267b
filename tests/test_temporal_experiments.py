"""The temporal-reuse experiments: the cost model fit, and each ``--quick``
mode end to end."""
import json

import numpy as np
import pytest

from experiments import temporal_reuse, temporal_table1
from experiments.sequence_runs import fit_cost_model


def test_cost_model_fit_recovers_background_and_reused_times():
    t = np.array([10.0] + [2.0] * 7)
    fit = fit_cost_model(t)
    assert fit["T_background_s"] == pytest.approx(10.0)
    assert fit["T_reused_s"] == pytest.approx(2.0)
    assert fit["rms_rel_residual"] < 1e-12


@pytest.mark.slow
def test_temporal_table1_quick(tmp_path):
    assert temporal_table1.main(["--quick", "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "temporal_table1.json").read_text())
    row = doc["rows"][0]
    assert row["max_diff_over_peak"] < 1e-6 and row["mean_recomputed_fraction"] < 1
    side = doc["settings"]["resolution"]
    assert all(f["samples"] == side[0] * side[1] for f in doc["frames"])   # 1 spp, as it says
    assert (tmp_path / "table.md").is_file() and (tmp_path / "fraction.png").is_file()


@pytest.mark.slow
def test_temporal_reuse_quick(tmp_path):
    assert temporal_reuse.main(["--quick", "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "temporal_reuse.json").read_text())
    assert doc["rows"][0]["max_diff_over_peak"] < 1e-6
    assert all(r["max_diff_over_peak"] < 1e-6 for r in doc["hybrid"])
    w, h = doc["settings"]["reuse_resolution"]
    assert all(f["samples"] == w * h for f in doc["frames"])   # 1 spp, as it says
    assert {r["method"] for r in doc["rows"]} == {"epipolar_tree", "raymarch"}
