"""Parameter sweeps over Dask: the plan, the runner, the output folder, its tables and plots."""
