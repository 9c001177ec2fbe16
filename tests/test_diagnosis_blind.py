"""Blind suite: data made by the BEM with the effect built into its scene; diagnosed with PSM effect models.

The BEM runs (tests/data/diagnosis/bem_worlds.npz, made by
``python -m electrosense.validation.studies.diagnosis_blind_data``) hold the noiseless
currents of the nominal scene and of each geometric effect built into the
BEM: the contact impedance as its boundary condition, the sphere as a mesh,
the other water depth and tank size as the tank mesh, the robot's offset as
the true poses. Output-side effects (conductivity, drift, channel gains) and
the bench noise (0.05 % on currents, 0.1 mm on positions) are added here. The
diagnosis gets the observations and the BEM baseline of the *believed* scene,
never the truth; its geometric effects are evaluated by the PSM (spheres at
the electrodes' centres) with Kelvin images for the sphere: other code and
other physics than the BEM that made the data.
"""
from pathlib import Path

import numpy as np
import pytest

from electrosense.validation.diagnosis.blind import BlindSetup, assemble
from electrosense.validation.diagnosis.forward import geometric_psm
from electrosense.validation.diagnosis.pipeline import default_effect_model_from, diagnose

DATA = Path(__file__).parent / "data" / "diagnosis" / "bem_worlds.npz"

pytestmark = pytest.mark.skipif(not DATA.exists(), reason="BEM blind data not generated")

#: (injected effects, output-side arguments of assemble)
CASES = {
    "none": ((), {}),
    "conductivity": (("conductivity",), {"conductivity": 0.02}),
    "temperature_drift": (("temperature_drift",), {"drift_per_hour": 0.06}),
    "channel_gain": (("channel_gain",), {"gains": [0.008, -0.006, 0.0]}),
    "contact_impedance": (("contact_impedance",), {}),
    "pose_offset": (("pose_offset",), {}),
    "water_depth": (("water_depth",), {}),
    "tank_size": (("tank_size",), {}),
    "unmodelled_object": (("unmodelled_object",), {}),
    "object+conductivity": (("unmodelled_object", "conductivity"), {"conductivity": -0.015}),
    "tank+gain": (("tank_size", "channel_gain"), {"gains": [0.0, 0.01, -0.008]}),
    "contact+drift": (("contact_impedance", "temperature_drift"), {"drift_per_hour": 0.05, "log_temperature": True}),
}
GEOMETRIC = ("contact_impedance", "pose_offset", "water_depth", "tank_size", "unmodelled_object")


@pytest.fixture(scope="module")
def bem():
    data = np.load(DATA)
    setup = BlindSetup()
    effect_model = default_effect_model_from(setup.sensor, setup.sigma_S_per_m, geometric_psm(setup.sensor))
    return setup, data, effect_model


@pytest.mark.parametrize("case", list(CASES))
def test_blind_case_names_the_injected_effect_and_shrinks_the_gap(bem, case):
    setup, data, effect_model = bem
    injected, output = CASES[case]
    geo = [e for e in injected if e in GEOMETRIC]
    I = data[f"I_{geo[0]}"] if geo else data["I_none"]
    seed = sum(map(ord, case))
    obs = assemble(setup, data["poses"], data["t_s"], data["passes"], I, np.random.default_rng(seed), **output)
    d = diagnose(obs, K_base=data["K_none"], effect_model=effect_model)
    if not injected:
        assert d.chosen == ["none"]
        assert d.gap_after < 1.5 * d.noise
        return
    assert d.chosen[0] in injected, f"{case}: chose {d.chosen}"
    if len(injected) == 1:
        assert d.chosen[0] == injected[0]
    else:
        assert set(injected) <= set(d.chosen), f"{case}: chose {d.chosen}"
    # at least 80 % of the held-out gap removed, or down to the noise floor when the gap was smaller than 5x it
    assert d.gap_after <= max(0.2 * d.gap_before, 1.25 * d.noise), (
        f"{case}: held-out gap {d.gap_before:.2e} -> {d.gap_after:.2e} (noise {d.noise:.2e})")
