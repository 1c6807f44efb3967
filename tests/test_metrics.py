"""ROI metrics on hand-built cases."""

import numpy as np
import pytest

from ipp_bench.core import metrics as M


def test_metrics_on_hand_built_case():
    mean = np.array([0.1, 0.5, 0.3, 0.9])
    var = np.array([0.04, 0.01, 0.25, 0.0])
    roi = M.belief_roi(mean, var, mu_th=0.4, beta=1.0)
    np.testing.assert_array_equal(roi, [False, True, True, True])  # 0.3 + 0.5 = 0.8 >= 0.4
    assert M.trace_roi(var, roi) == pytest.approx(0.26)
    truth = np.array([0.0, 1.0, 0.0, 1.0])
    troi = M.truth_roi(truth, 0.4)
    np.testing.assert_array_equal(troi, [False, True, False, True])
    assert M.rmse_roi(mean, truth, troi) == pytest.approx(np.sqrt((0.25 + 0.01) / 2))
    assert M.reduction_pct(200.0, 50.0) == pytest.approx(75.0)
    assert M.info_gain_reward(2.0, 1.5) == pytest.approx(2.5)
    assert M.info_gain_reward(0.0, 0.0) == 0.0
    assert np.isnan(M.rmse_roi(mean, truth, np.zeros(4, bool)))
