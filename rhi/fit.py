"""``rhi fit`` in memory, over arrays, as sbi's simulate / train / sample (:mod:`rhi.master.fit.memory`).

Examples
--------
A fit's plan and data from files, prior draws, simulated participants, an estimator and a posterior::

    import rhi
    data = rhi.fit.read_data("docs/fit/default_run.csv")
    plan = rhi.fit.read_plan("docs/fit/recovery.toml", data)
    theta = rhi.fit.draw(plan, 200)                  # (200, parameters), the inference space
    x = rhi.fit.simulate(plan, data, theta)          # (200, cells x measures)
    estimator = rhi.fit.train(plan, theta, x)
    samples = rhi.fit.sample(plan, estimator, x[0], 100, seed=1)   # (100, parameters), their own units

The model at one point (a fit's point.csv, the parameters in their own units), 20 studies of it::

    x = rhi.fit.at_point(plan, data, {"decoder.visual_variance": 20.0}, count=20)
"""
from rhi.master.fit.data import read_data
from rhi.master.fit.memory import at_point, draw, sample, simulate, train
from rhi.master.fit.plan import read_plan

__all__ = ["read_data", "read_plan", "draw", "simulate", "train", "sample", "at_point"]
