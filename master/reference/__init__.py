"""The reference tables of docs/, written from the code: configuration keys and defaults, the output
columns, the FMU ports, the Dask worker's settings.

Each table sits in a docs page between ``<!-- generated: NAME -->`` and ``<!-- end generated: NAME -->``.
``python -m rhi.master.reference`` rewrites them; ``python -m rhi.master.reference --check`` lists the stale
ones and exits 1 (tests/test_docs.py runs the same check).
"""
