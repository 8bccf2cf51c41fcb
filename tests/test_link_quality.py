"""Link quality and identification: a record the link lost too much of is not used (its attempt is
rejected and retried), however well it fits; one that lost a little is."""
from __future__ import annotations

import math
import random

import pytest

from behaviors.identification import IdentificationManoeuvre, ManoeuvreConfig
from companion.numerics.sampling import SamplingRule, sampling_quality
from companion.procedures.runner import run_behavior
from harness.inprocess import InProcessLink


def test_sampling_quality_from_time_stamps():
    times = [i * 0.05 for i in range(200)]
    clean = sampling_quality(times)
    assert clean.period_s == pytest.approx(0.05) and clean.missing == pytest.approx(0.0, abs=1e-9)
    assert clean.verdict(SamplingRule()) is None
    rng = random.Random(3)
    lossy = sampling_quality([t for i, t in enumerate(times) if i in (0, 199) or rng.random() > 0.3])
    assert 0.2 < lossy.missing < 0.4 and "lost" in lossy.verdict(SamplingRule())
    gap = sampling_quality([t for t in times if not 4.0 < t < 4.5])
    assert gap.max_gap_s == pytest.approx(0.5) and "gap" in gap.verdict(SamplingRule())
    assert sampling_quality([0.0, 0.05]).verdict(SamplingRule()) is not None


class LossyLink(InProcessLink):
    """Loses snapshots (as a lossy radio would) while ``losing`` says so."""

    def __init__(self, loss, **kwargs) -> None:
        super().__init__(**kwargs)
        self.loss = loss
        self.rng = random.Random(11)

    def next_telemetry(self, timeout_s: float = 5.0):
        while True:
            sample = super().next_telemetry(timeout_s)
            if self.rng.random() >= self.loss(sample.time_s):
                return sample


CONFIG = ManoeuvreConfig(settle_s=10.0, resettle_s=8.0, max_attempts=2, stop_on_convergence=False)


def test_a_record_the_link_lost_a_third_of_is_rejected_and_the_fresh_one_accepted():
    link = LossyLink(lambda t: 0.35 if t < 40.0 else 0.0, seed=4)
    manoeuvre = IdentificationManoeuvre(CONFIG, thrust=0.7)
    outcome = run_behavior(link, manoeuvre)
    first, second = manoeuvre.attempts
    assert not first.accepted and "lost" in first.rejected_for and first.sampling["training"]["missing"] > 0.25
    assert math.isfinite(first.r2)  # scored, yet not used: the record says too little
    assert second.accepted and second.rejected_for is None and outcome.status == "completed"
    assert any("link lost samples" in text for text in link.status_texts)


def test_a_little_loss_does_not_reject_a_record():
    link = LossyLink(lambda t: 0.03, seed=4)
    manoeuvre = IdentificationManoeuvre(CONFIG, thrust=0.7)
    run_behavior(link, manoeuvre)
    assert manoeuvre.attempts[0].accepted and manoeuvre.attempts[0].sampling["training"]["missing"] < 0.1
