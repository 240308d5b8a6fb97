"""`rhi fit`: the model fitted to participants' data by simulation-based inference (neural posterior estimation
with the ``sbi`` package), with its calibration on held-out simulated participants (docs/fit.md).

- :mod:`rhi.master.fit.data`: the data file, checked, and each participant's summary statistics;
- :mod:`rhi.master.fit.plan`: the fit file: parameters, priors, settings; the prior sampled;
- :mod:`rhi.master.fit.simulate`: simulated participants on the sweep machinery (lockstep, resumable);
- :mod:`rhi.master.fit.inference`: training, saving and sampling the estimator;
- :mod:`rhi.master.fit.calibration`: simulation-based calibration, coverage, recovery;
- :mod:`rhi.master.fit.report`: tables and figures; :mod:`rhi.master.fit.run`: the whole fit.

This module stays light (no torch, no sbi) so that the command line can list the command.
"""
