"""The master's per-step time against ``fmpy.simulate_fmu`` on the same body FMU."""
from __future__ import annotations

import sys
import time

import numpy as np

OUTPUTS = ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y")


def master_overhead(steps: int, step_size: float = 0.02) -> dict:
    """Per-step wall time of the same body FMU (B = 1) under fmpy.simulate_fmu and under this master driving the
    FMUComponent adapter alone, from time stamps after each step (setup excluded), best of three interleaved rounds."""
    import tempfile
    from pathlib import Path

    from fmpy import read_model_description, simulate_fmu

    from rhi.components.body.contract import BODY_CONTRACT
    from rhi.components.fmu import FMUComponent, extracted, guard_library
    from rhi.master.cosim import simulate
    from rhi.master.export.body import build_fmu
    from rhi.master.cosim import System

    # Both set the two inputs (held at 0) before every step and read the six outputs after it.
    signal = np.array([(0.0, 0.0, 0.0), (steps * step_size, 0.0, 0.0)],
                      dtype=[("time", float), ("u_shoulder", float), ("u_elbow", float)])

    def under_fmpy(stamp):
        simulate_fmu(unzipdir, stop_time=steps * step_size, step_size=step_size, output_interval=step_size,
                     input=signal, output=list(OUTPUTS), model_description=description, validate=False,
                     step_finished=lambda *_: stamp() or True)

    def under_master(stamp):
        timings.append(simulate(System([FMUComponent(path, "body", BODY_CONTRACT)], []), steps * step_size, step_size,
                                record=[f"body.{o}" for o in OUTPUTS], progress=lambda *_: stamp()).timings)

    def per_step(run):
        stamps = []
        run(lambda: stamps.append(time.perf_counter()))
        return (stamps[-1] - stamps[0]) / (len(stamps) - 1)

    saved, timings = list(sys.path), []  # a pythonfmu FMU prepends its resources to sys.path
    with tempfile.TemporaryDirectory(prefix="rhi_bench_") as folder:
        path = str(build_fmu(Path(folder) / "Body.fmu", "native"))
        description = read_model_description(path)
        unzipdir = extracted(path)
        guard_library(unzipdir, description.coSimulation.modelIdentifier)
        try:  # interleaved, so that a slow patch of the machine hits both alike
            fmpy_step, master_step = np.min([[per_step(under_fmpy), per_step(under_master)] for _ in range(3)],
                                            axis=0).tolist()
        finally:
            sys.path[:] = saved
    return {"fmu": "native body (pythonfmu)", "steps": steps, "fmpy_step_s": fmpy_step, "master_step_s": master_step,
            "wall_ratio": master_step / fmpy_step,
            "of_which_master_loop_s": min(t["master_overhead_s"] for t in timings) / steps,
            "of_which_adapter_and_fmu_s": min(t["step_s.body"] for t in timings) / steps}
