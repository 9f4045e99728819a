"""Speed figures of the bench's inner loop (printed by a benchmark, never asserted in tests).

``python -m firmware_sim.perf`` drives both wheels through their 1 kHz PID on a
changing setpoint profile and prints the wall time per 10 ms bench step spent in
physics and drive firmware (:meth:`ChairSim.advance`), without any bus traffic.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from dbc.codec import AxisState, Node, SetAxisState, SetInputVel
from firmware_sim.config import BenchConfig, default_config
from firmware_sim.drive import Out
from firmware_sim.sim import ChairSim


@dataclass(frozen=True, slots=True)
class StepCost:
    """Wall time of plant + both drive loops per bench step (best of ``repeats``)."""

    steps: int
    best_us_per_step: float
    median_us_per_step: float

    @property
    def real_time_factor(self) -> float:
        """Simulated time per wall time for the physics alone (10 ms steps)."""
        return 10_000.0 / self.best_us_per_step


def measure_step_cost(
    config: BenchConfig | None = None, *, steps: int = 1000, repeats: int = 5
) -> StepCost:
    """Time :meth:`ChairSim.advance` over ``steps`` steps, ``repeats`` times."""
    sim = ChairSim(config or default_config())
    out: Out = []
    for node in (Node.LEFT, Node.RIGHT):
        sim.handle(node, SetAxisState(AxisState.CLOSED_LOOP_CONTROL), out)
    runs = []
    k = 0
    for _ in range(repeats):
        elapsed = 0
        for _ in range(steps):
            t = k * 0.01
            k += 1
            sim.handle(Node.LEFT, SetInputVel(0.3 + 0.1 * math.sin(0.5 * t)), out)
            sim.handle(Node.RIGHT, SetInputVel(0.3 + 0.1 * math.cos(0.3 * t)), out)
            t0 = time.perf_counter_ns()
            sim.advance()
            elapsed += time.perf_counter_ns() - t0
        runs.append(elapsed / steps / 1e3)
    runs.sort()
    return StepCost(steps, runs[0], runs[len(runs) // 2])


def main() -> None:
    """Print the best and median cost of one 10 ms bench step (plant and two drive loops)."""
    cost = measure_step_cost()
    print(
        f"plant + 2 drive loops per 10 ms step: best {cost.best_us_per_step:.1f} us, "
        f"median {cost.median_us_per_step:.1f} us ({cost.real_time_factor:.0f}x real time)"
    )


if __name__ == "__main__":
    main()
