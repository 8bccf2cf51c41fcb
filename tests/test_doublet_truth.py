"""The stated truth of a 3-DOF hull for a doublet identification (eq. S.6): the first-order model
whose heading response to the campaign's training doublet best matches the linearised hull's, beside
Nomoto's classic K/T; and the nonlinear hull's own fit, which meets it at a small amplitude and leaves
it at the campaign's (the hull's amplitude nonlinearity)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from sim.doublet_truth import Doublet, doublet_response_fit, first_order_heading, linear_heading
from sim.nomoto import linearized_3dof
from sim.preset import load_preset

DOUBLET = Doublet(amplitude=0.1, pre_s=0.5, period_s=4.0, window_s=12.0)


@pytest.fixture(scope="module")
def rudder():
    return load_preset("boat-3dof")


def _cost(preset, speed, a22, b2, delta0=0.0):
    t, u = DOUBLET.inputs()
    return float(np.sum((first_order_heading(a22, b2, u - delta0) - linear_heading(preset, speed, u)) ** 2))


def test_the_doublet_equivalent_model_fits_the_hulls_response_better_than_nomotos_classic(rudder):
    fit = doublet_response_fit(rudder, 1.5, DOUBLET)
    classic = linearized_3dof(rudder, 1.5)
    assert fit["r2"] > 0.98
    best = _cost(rudder, 1.5, fit["a22"], fit["b2"])
    assert best < 0.5 * _cost(rudder, 1.5, classic["a22"], classic["b2"])
    for a22, b2 in ((fit["a22"] * 1.05, fit["b2"]), (fit["a22"], fit["b2"] * 0.95)):  # a local minimum, not a guess
        assert _cost(rudder, 1.5, a22, b2) > best * 0.999
    # the doublet weights frequencies above the classic model's: |a22| well above 1/(T1 + T2 − T3)
    assert fit["a22"] < 1.25 * classic["a22"]


def test_a_linear_truth_does_not_depend_on_the_amplitude_and_the_nonlinear_hull_meets_it_when_small(rudder):
    small = doublet_response_fit(rudder, 1.5, Doublet(0.01, 0.5, 4.0, 12.0))
    large = doublet_response_fit(rudder, 1.5, Doublet(0.26, 0.5, 4.0, 12.0))
    assert large["a22"] == pytest.approx(small["a22"], rel=1e-6) and large["b2"] == pytest.approx(small["b2"], rel=1e-6)
    near = doublet_response_fit(rudder, 1.5, Doublet(0.005, 0.5, 4.0, 12.0), linear=False)
    far = doublet_response_fit(rudder, 1.5, Doublet(0.26, 0.5, 4.0, 12.0), linear=False)
    assert near["a22"] == pytest.approx(small["a22"], rel=0.01) and near["b2"] == pytest.approx(small["b2"], rel=0.01)
    assert abs(far["a22"] / small["a22"] - 1.0) > 0.05  # the campaign's 0.26 rad: the hull is not linear there


def test_sim_linearize_reports_both_truths_for_a_training_doublet(capsys):
    from sim.__main__ import main

    assert main(["linearize", "--preset", "boat-skid", "--speed", "1.5", "--doublet", "0.1,0.5,4,12", "--json"]) == 0
    truth = json.loads(capsys.readouterr().out)
    assert truth["doublet_equivalent"]["model"] == "linearised" and truth["doublet_nonlinear"]["model"] == "nonlinear"
    assert truth["doublet_equivalent"]["a22"] < truth["a22"] < 0.0  # faster than the classic K/T
    assert truth["doublet_equivalent"]["doublet"]["window_s"] == 12.0
