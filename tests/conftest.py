"""Settings for the test session."""
import os

# Passive OpenMP waiting, as `rhi` sets it in master.commands.cli.main (see the reason there): the tests
# load torch themselves, not through main(), and conftest runs before any test module imports it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
