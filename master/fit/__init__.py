"""`rhi fit`: the model fitted to participants' data by simulation-based inference (neural posterior estimation
with the ``sbi`` package), with its calibration on held-out simulated participants (docs/fit.md).

- :mod:`master.fit.data`: the data file, checked, and each participant's summary statistics;
- :mod:`master.fit.plan`: the fit file: parameters, priors, settings; the prior sampled;
- :mod:`master.fit.simulate`: simulated participants on the sweep machinery (lockstep, resumable);
- :mod:`master.fit.inference`: training, saving and sampling the estimator;
- :mod:`master.fit.calibration`: simulation-based calibration, coverage, recovery;
- :mod:`master.fit.report`: tables and figures; :mod:`master.fit.run`: the whole fit.

This module stays light (no torch, no sbi) so that the command line can list the command.
"""
