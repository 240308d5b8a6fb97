"""A model of one's own, in one file: the paper's model with the common-cause belief gamma held fixed.

The paper's brain updates gamma from the touches' timing (eqs. 8-9). Here gamma stays at ``fixed_gamma.gamma``
whatever the touches, so vision is weighed the same under synchronous and asynchronous touch: the drift no
longer tells the two apart. Run it as any built-in model::

    rhi experiment --model examples/my_model.py:FixedGamma --out results
    rhi sweep --config sweep.toml --model examples/my_model.py:FixedGamma --out sweep
    rhi fit --data data.csv --config fit.toml --model examples/my_model.py:FixedGamma --out fit

and ``fixed_gamma.gamma`` is a configuration key like any other (``--config``, a sweep's grid, a fit's prior).
"""
from rhi.components.brain.integrator import Brain
from rhi.master.models.paper import PaperModel


class FixedGammaBrain(Brain):
    """The paper's brain with gamma = gamma0 at every step (no update from the touches)."""

    def common_cause(self, t, h, pair):
        return self.values["gamma0"].copy()


class FixedGamma(PaperModel):
    """The paper's model, its brain's gamma fixed at the configuration's ``fixed_gamma.gamma``."""

    name = "fixed-gamma"
    summary = "the paper's model with gamma fixed (fixed_gamma.gamma): vision weighed the same whatever the touches"
    settings_file = ""
    own_settings = {"fixed_gamma": {"gamma": 0.5}}  # a new table of keys, as master/models/causal.toml adds [causal]
    parameter_sources = {**PaperModel.parameter_sources, "brain.gamma0": "fixed_gamma.gamma"}

    def brain(self):
        return FixedGammaBrain()
