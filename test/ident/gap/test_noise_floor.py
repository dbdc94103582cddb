"""The held-out noise floor gap prints beside the held-out NRMSE is the NRMSE of a perfect model.

A true rig replayed on its own recordings (white θ noise of a known σ): the error is the noise, so
each recording's NRMSE equals its noise floor (σ over its range), on a recording that moves (an
APRBS, a floor of a few thousandths) and on one that does not (the rod at rest: range a few σ, a
floor of order 0.3); the report line says the error is the sensor's noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from aeropend_ident.gap.effects import MeasurementMap
from aeropend_ident.gap.report import noise_floor_text
from aeropend_ident.gap.which.data import prepare
from aeropend_ident.gap.which.metrics import gap_metrics
from aeropend_sim.params import rig_from_dict
from aeropend_sim.recording import Recording
from bench.bench_gap_independent import rig_dict
from bench.fixtures import truth_plant as tp

SIGMA = 2e-3  # θ noise [rad]


def test_a_perfect_model_is_at_the_noise_floor() -> None:
    p = tp.PlantParams()
    plant = tp.TruthPlant(p)
    rig = rig_from_dict(rig_dict(p, "lab_nominal"), where="test")
    rng = np.random.default_rng(11)

    def rec(duty: np.ndarray, source: str) -> Recording:
        true = plant.simulate(duty)
        theta = true["theta"] + SIGMA * rng.standard_normal(duty.size)
        return Recording(t=true["t"], duty=true["duty"], channels={"theta": theta}, source=source)

    moving = rec(tp.aprbs(30.0, seed=3), "aprbs")
    resting = rec(np.zeros(int(8.0 / tp.DT)), "at rest")
    m = gap_metrics(rig, MeasurementMap(), prepare([moving, resting], frozenset({"theta"})))
    runs = {r["recording"]: r for r in m["free_run"]}
    for name in ("aprbs", "at rest"):
        r = runs[name]
        print(f"{name}: NRMSE {r['nrmse']:.5f}, noise floor {r['noise_floor_nrmse']:.5f} "
              f"(noise σ {r['noise_sd'] * 1e3:.3f} mrad, range {r['range'] * 1e3:.2f} mrad)")
        assert r["noise_sd"] == pytest.approx(SIGMA, rel=0.15)
        assert r["nrmse"] == pytest.approx(r["noise_floor_nrmse"], rel=0.15)
    assert runs["aprbs"]["noise_floor_nrmse"] < 0.01 < 0.1 < runs["at rest"]["noise_floor_nrmse"]
    assert m["noise_floor_nrmse"] == pytest.approx(np.mean([r["noise_floor_nrmse"] for r in runs.values()]))
    h = {"heldout_nrmse_nominal": m["nrmse"], "heldout_noise_floor_nrmse": m["noise_floor_nrmse"]}
    assert "the held-out error is the sensor's noise" in noise_floor_text(h)
    assert noise_floor_text({**h, "heldout_nrmse_nominal": 3.0 * m["noise_floor_nrmse"]}) == ""


def test_a_share_of_a_gap_at_the_noise_floor_stays_a_share() -> None:
    """The share of the validation gap above the noise a model removes is taken of at least the
    smallest gap that counts as one (ABOVE_NOISE × the noise part + the rounding chance): a
    nominal just above its noise part made a noise-sized change read 146.8 (lab case 0)."""
    from types import SimpleNamespace

    from aeropend_ident.gap.which.context import ABOVE_NOISE, _Setup

    st = SimpleNamespace(sse_val0=1.001, noise_sse=1.0, chance_c={"theta": 0.01})
    least = (ABOVE_NOISE - 1.0) * 1.0 + 0.01
    assert _Setup.above_noise_share(st, 0.999) == pytest.approx(0.002 / least)  # not 2.0
    assert _Setup.above_noise_share(st, 1.05) == pytest.approx(-0.049 / least)  # not −49
    far = SimpleNamespace(sse_val0=3.0, noise_sse=1.0, chance_c={"theta": 0.01})
    assert _Setup.above_noise_share(far, 2.0) == pytest.approx(0.5)  # a real gap: unchanged
    assert _Setup.above_noise_share(far, 2.0, base=0.9) == 0.0  # a base under the noise: nothing to share
