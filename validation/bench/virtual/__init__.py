"""The virtual bench: a simulated tank, sensor and robot that talks the bench's serial protocol.

It is a simulator for tests and demos, and says so in everything it produces
(the hello line's device name, the ``source`` of every file it writes).

* :mod:`.trajectory`: wall-to-wall passes, lines, grids, several passes;
* :mod:`.effects`: physical effects built into the physics (conductivity,
  temperature drift, contact impedance, channel gains, pose offset, water depth,
  tank size, an unmodelled object);
* :mod:`.bench`: :class:`VirtualBench`, the samples of a run (model + noise + effects);
* :mod:`.faults`: corrupt checksums, dropped lines, garbage bytes, disconnections, restarts;
* :mod:`.transport`: a pseudo-terminal or a loopback socket that can vanish and come back;
* :mod:`.device`: :class:`BenchDevice`, the firmware that streams a run.
"""
from electrosense.validation.bench.virtual.bench import SIMULATOR_LABEL, BenchNoise, SimulatedRun, VirtualBench
from electrosense.validation.bench.virtual.device import TRUTH_COLUMNS, BenchDevice, DeviceReport
from electrosense.validation.bench.virtual.effects import EFFECT_NAMES, Effects
from electrosense.validation.bench.virtual.faults import FAULT_KINDS, FaultPlan
from electrosense.validation.bench.virtual.trajectory import grid, line, parse_path, repeat_passes, wall_to_wall
from electrosense.validation.bench.virtual.transport import NoHost, PtyTransport, SocketTransport

__all__ = [
    "SIMULATOR_LABEL", "BenchNoise", "SimulatedRun", "VirtualBench", "BenchDevice", "DeviceReport", "TRUTH_COLUMNS",
    "Effects", "EFFECT_NAMES", "FaultPlan", "FAULT_KINDS", "parse_path", "repeat_passes", "wall_to_wall", "line",
    "grid", "PtyTransport", "SocketTransport", "NoHost",
]
