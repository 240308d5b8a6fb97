"""Run-time helpers: worker processes whose results do not depend on the schedule (``pool.py``), and the
run settings passed as one object (``context.py``)."""
