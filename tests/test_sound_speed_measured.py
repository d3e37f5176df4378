"""The speed of sound from measured RIRs: the dEchorate loudspeaker's direct paths at its 12
calibrated microphones (real data; skipped, naming the paths tried, when the data are absent)."""

import numpy as np
import pytest

from rangeslam.acoustics.echoes import detect_echoes_many
from rangeslam.acoustics.pipeline import MEASURED_RIR_OPTIONS
from rangeslam.acoustics.sound_speed import estimate_sound_speed
from rangeslam.datasets import load_rirs
from rangeslam.status import Status


@pytest.fixture
def measured(dechorate_dir):
    """The 12 measured RIRs, their detections (the measured preset's detection options) and the
    calibrated geometry and c (345.844 m/s, 24 degC, from the dataset's authors)."""
    loaded = load_rirs(dechorate_dir / "rirs_src0_12mics.npz")
    dets = detect_echoes_many(loaded.rirs, loaded.fs, **MEASURED_RIR_OPTIONS["detect_options"])
    return loaded, dets


@pytest.mark.parametrize("c0", [335.0, 343.0, 352.0])
def test_c_from_measured_direct_paths_agrees_with_the_calibrated_c(measured, c0):
    """From any start within 3% the fit reaches one answer (measured: 342.2 +- 2.9 m/s, RMS
    residual 5 mm), whose reported standard deviation covers the calibrated c within two of
    itself (measured 1.3), and the loudspeaker fitted with it is within 5 cm of the calibrated
    one (measured 4.0 cm). The reported uncertainty is what makes this a fair answer: direct
    paths of 1.5-4 m fix c to under 1% only."""
    loaded, dets = measured
    est = estimate_sound_speed(dets, loaded.mics, c0=c0)
    assert est.status is Status.CONVERGED and est.n_used == 12
    assert abs(est.c - loaded.c) <= 2.0 * est.c_std
    assert 0.5 < est.c_std < 5.0  # neither an overconfident nor a vacuous interval
    assert np.linalg.norm(est.source - loaded.source) < 0.05
    assert est.residual_rms < 0.01


def test_c_from_too_few_measured_direct_paths_is_not_identifiable(measured):
    """Five microphones (four unknowns, one degree of freedom) do not give c: NOT_IDENTIFIABLE,
    c left at the start and an infinite standard deviation."""
    loaded, dets = measured
    est = estimate_sound_speed(dets[:5], loaded.mics[:5], c0=343.0)
    assert est.status is Status.NOT_IDENTIFIABLE and est.c == 343.0 and est.c_std == np.inf
    assert "5 microphones with a direct path, 6 needed" in est.message
