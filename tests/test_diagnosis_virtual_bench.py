"""Data made by other code: the project's virtual bench (validation.bench.virtual) with its own effects, PSM world.

The diagnosis runs with ``model="psm"`` and is told nothing but the observations.
"""
import pytest

from electrosense.meshes.sensor import preset
from electrosense.meshes.tank import Tank
from electrosense.validation.diagnosis.blind import blind_poses
from electrosense.validation.diagnosis.observations import Observations
from electrosense.validation.diagnosis.pipeline import diagnose

bench_sim = pytest.importorskip("electrosense.validation.bench.virtual.bench")
from electrosense.validation.bench.virtual.effects import Effects  # noqa: E402

CASES = [
    ([], ["none"]),
    (["temperature_drift=1.0"], ["temperature_drift"]),
    (["pose_offset=0.01,-0.005,0,0.03"], ["pose_offset"]),
    (["conductivity=-2%", "unmodelled_object=sphere,0.1,0.07,0,0.03,conducting"], ["conductivity", "unmodelled_object"]),
]


@pytest.mark.parametrize("effects,expected", CASES, ids=["none", "drift", "pose", "conductivity+object"])
def test_virtual_bench_effects_are_named(effects, expected):
    sensor, tank = preset("angels-4"), Tank((1.0, 1.0, 1.0))
    poses, _, passes = blind_poses(50)
    # the noise seeded: the diagnosis's verdict is a test at a false-alarm rate, and an unseeded run once named
    # nothing in the effect-free case (0 of 30 seeds do)
    bench = bench_sim.VirtualBench(sensor, tank, 0.0354, model="psm", effects=Effects.parse(effects), seed=1)
    run = bench.run(poses, rate_hz=0.1, passes=passes)
    obs = Observations(run.poses, run.currents_A, sensor, tank, 0.0354, U_V=run.U_V, t_s=run.t_s,
                       passes=run.passes, temperature_C=run.temp_C, meta={"temperature_C": 20.0})
    d = diagnose(obs, model="psm")
    assert sorted(d.chosen) == sorted(expected)
    assert d.gap_after <= max(0.2 * d.gap_before, 1.5 * d.noise)
