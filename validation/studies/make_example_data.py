"""Bundled example bench logs: generate them with the virtual bench (SYNTHETIC data, labelled so).

The files in ``validation/data`` are small synthetic bench logs made by the
virtual bench (:mod:`electrosense.validation.bench.virtual`) with the bench's noise (0.05 % on
currents, 0.1 mm on positions) in the paper's set-up: the 1 m tank, water of
nominal conductivity 0.0354 S/m (354 uS/cm), the sensor in the horizontal
mid-plane. As on the paper's bench, the true conductivity is lower than the
nominal one by the paper's correction (2.06 % for angels-2, 2.37 % for
angels-4), so that a model run with the nominal conductivity shows the paper's
gap and a conductivity correction removes it.

=============================  ===========================================================
file                           content
=============================  ===========================================================
angels-2_wall-to-wall.csv      angels-2, x from -0.38 to 0.38 m at y = 0, yaw 0, 161 poses
angels-4_wall-to-wall.csv      angels-4, x from -0.37 to 0.37 m at y = 0, yaw 0, 161 poses
angels-4_passes.csv            angels-4, 3 passes of 41 poses (``pass`` column): along x at
                               y = 0, back along x at y = 0.2 m, along y at x = 0 with yaw
                               pi/2; the water warms by 0.3 K over the run
angels-4_object.csv            angels-4, x from -0.37 to 0.37 m at y = 0, 81 poses, with a
                               conducting sphere (radius 2 cm at x = 0.1, y = 0.06 m) that
                               the meta does not mention
=============================  ===========================================================

The currents come from the BEM (the paper's reference, which reproduces its
bench), so that a PSM run on these logs shows the PSM's own error on top of
the conductivity gap, as in the paper.

Why +-0.38 m: the paper's figures span the aquarium from -0.4 to 0.4 m but
its near-wall data reach |x| = 0.38 m, and the bench-log spec's example starts
at x = -0.38; at |x| = 0.40 m the 20 cm sensor's tip would touch the wall of
the 1 m tank. angels-4 stops at +-0.37 m: its PSM is longer than the sensor
(the paper's fit: 23.39 cm between the outer sphere centres), and at 0.38 m
its tail sphere would reach beyond the wall, so no PSM could be run on the log.

Run ``python -m electrosense.validation.studies.make_example_data`` to regenerate them into
a temporary folder and compare with the bundled ones (figures: resistance
mid-tank and at the walls, side by side with the paper's), or with ``--out
validation/data --overwrite`` to replace them.
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["main", "EXAMPLES", "make_example", "DATA_DIR"]

DATA_DIR = Path(__file__).resolve().parent.parent / "data"
SIGMA_NOMINAL_S_PER_M = 0.0354
RATE_HZ = 10.0

#: file name -> (sensor, passes as path specs, effects, seed)
EXAMPLES = {
    "angels-2_wall-to-wall.csv": ("angels-2", ["line:-0.38,0,0,0:0.38,0,0,0:161"], ["conductivity=-2.06%"], 2),
    "angels-4_wall-to-wall.csv": ("angels-4", ["line:-0.37,0,0,0:0.37,0,0,0:161"], ["conductivity=-2.37%"], 4),
    "angels-4_passes.csv": ("angels-4", ["line:-0.37,0,0,0:0.37,0,0,0:41", "line:0.37,0.2,0,0:-0.37,0.2,0,0:41",
                                         "line:0,-0.37,0,1.5707963267948966:0,0.37,0,1.5707963267948966:41"],
                            ["conductivity=-2.37%", "temperature_drift=0.3"], 40),
    "angels-4_object.csv": ("angels-4", ["line:-0.37,0,0,0:0.37,0,0,0:81"],
                            ["conductivity=-2.37%", "unmodelled_object=sphere,0.1,0.06,0,0.02,conducting"], 41),
}

#: the paper's resistances (read off its figures 6 and 8), ohm
PAPER = {"angels-2": "about 600 mid-tank, rising towards the walls (axis 600-800)",
         "angels-4": "900 to 1600 near the walls (|x| = 0.28-0.38 m)"}


def make_example(name: str, model: str = "bem", out_dir: Path = DATA_DIR, overwrite: bool = False) -> Path:
    """Generate one example log (see ``EXAMPLES``) into ``out_dir``."""
    import pandas as pd

    from electrosense.meshes.sensor import preset
    from electrosense.meshes.tank import Tank
    from electrosense.validation.bench.log import write_bench_log
    from electrosense.validation.bench.virtual import Effects, VirtualBench, parse_path

    sensor_name, paths, effects, seed = EXAMPLES[name]
    tank = Tank((1.0, 1.0, 1.0))
    segments = [parse_path(p, tank.size_m) for p in paths]
    poses = np.concatenate(segments)
    passes = np.repeat(np.arange(len(segments)), [len(s) for s in segments])
    bench = VirtualBench(preset(sensor_name), tank, SIGMA_NOMINAL_S_PER_M, model=model,
                         effects=Effects.parse(effects), seed=seed)
    run = bench.run(poses, rate_hz=RATE_HZ, passes=passes)
    columns = list(run.columns)
    if len(segments) == 1:
        columns.remove("pass")
    rows = [run.record_values(i) for i in range(len(run))]
    frame = pd.DataFrame(rows, columns=list(run.columns))[columns]
    meta = {
        "sensor": sensor_name, "emitter": bench.sensor.emitter, "tank_m": [1.0, 1.0, 1.0], "water_depth_m": 1.0,
        "sigma_S_per_m": SIGMA_NOMINAL_S_PER_M, "temperature_C": 20.0, "voltage_V": 1.0,
        "source": f"SYNTHETIC example, not a measurement: {bench.describe()}; paths {' | '.join(paths)} at "
                  f"{RATE_HZ:g} Hz; seed {seed}",
        "notes": "generated by python -m electrosense.validation.studies.make_example_data",
    }
    return write_bench_log(Path(out_dir) / name, meta, frame, overwrite=overwrite)


def _figures(path: Path) -> str:
    from electrosense.validation.bench.log import read_bench_log

    log = read_bench_log(path)
    R = log.resistance_ohm
    first = log.passes == log.passes[0]
    x = log.poses[first, 0]
    mid = np.argmin(np.abs(x))
    cols = ", ".join(f"R{k} {R[first][mid, j]:.0f} / {R[first][0, j]:.0f} / {R[first][-1, j]:.0f}"
                     for j, k in enumerate(log.receivers))
    return f"{len(log):4d} rows; mid-tank / x = {x[0]:+.2f} / x = {x[-1]:+.2f} m (ohm): {cols}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="make_example_data", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None,
                        help="folder to write into (default: a temporary folder, then compared with the bundled files)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing files in --out")
    parser.add_argument("--model", choices=["psm", "bem"], default="bem", help="model of the virtual bench")
    parser.add_argument("--only", default=None, help="one file name of the set")
    args = parser.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="esense-examples-"))
    out.mkdir(parents=True, exist_ok=True)
    names = [args.only] if args.only else list(EXAMPLES)
    for name in names:
        path = make_example(name, args.model, out, args.overwrite)
        sensor = EXAMPLES[name][0]
        print(f"{name:28s} {_figures(path)}")
        print(f"{'':28s} paper ({sensor}, measured): {PAPER[sensor]}")
        bundled = DATA_DIR / name
        if bundled.exists() and bundled.resolve() != path.resolve():
            from electrosense.validation.bench.log import read_bench_log

            a, b = read_bench_log(path).currents_A, read_bench_log(bundled).currents_A
            diff = "shapes differ" if a.shape != b.shape else f"max relative difference {np.max(np.abs(a / b - 1)):.2e}"
            print(f"{'':28s} vs the bundled file: {diff}")
    print(f"written to {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
