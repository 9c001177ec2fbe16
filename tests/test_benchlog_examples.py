"""The bundled example logs: strict reading, labelled synthetic, the paper's set-up."""
import numpy as np
import pytest

from electrosense.validation.bench.log import read_bench_log
from electrosense.validation.bench.virtual import parse_path
from electrosense.validation.studies.make_example_data import DATA_DIR, EXAMPLES


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_bundled_example_reads_and_says_it_is_synthetic(name):
    log = read_bench_log(DATA_DIR / name)
    sensor, paths, effects, _ = EXAMPLES[name]
    assert log.warnings == [] and log.sensor.name == sensor and log.emitter == log.sensor.n_electrodes
    assert "SYNTHETIC" in log.meta["source"] and "SIMULATED" in log.meta["source"]
    assert all(e in log.meta["source"] for e in effects)
    assert log.tank.size_m == (1.0, 1.0, 1.0) and log.sigma_S_per_m == 0.0354
    assert len(log.pass_numbers) == len(paths)
    assert np.all(log.currents_A > 0) and np.all(np.diff(log.t_s) > 0)
    for number, spec in zip(log.pass_numbers, paths):  # the logged poses are the nominal path, to 0.1 mm
        np.testing.assert_allclose(log.select_pass(number).poses, parse_path(spec), atol=5.1e-5)
    first = log.select_pass(log.pass_numbers[0]).poses
    assert -first[0, 0] == first[-1, 0] >= 0.37 and np.all(first[:, 1:] == 0.0)  # wall to wall at y = 0, yaw 0


def test_wall_to_wall_resistance_rises_towards_the_walls_as_in_the_paper():
    R = read_bench_log(DATA_DIR / "angels-2_wall-to-wall.csv").resistance_ohm[:, 0]
    mid = len(R) // 2
    assert R[0] > 1.03 * R[mid] and R[-1] > 1.03 * R[mid]
    assert 550 < R[mid] < 700  # the paper's figure 6: about 600 ohm mid-tank
    R4 = read_bench_log(DATA_DIR / "angels-4_wall-to-wall.csv").resistance_ohm
    # four electrodes tell the walls apart: R2 and R3 rise at the tail's wall (x < 0) and fall at the head's
    assert np.all(R4[0, 1:] > R4[mid, 1:]) and np.all(R4[-1, 1:] < R4[mid, 1:])
