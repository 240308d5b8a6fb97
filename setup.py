"""The package's C part; everything else is in pyproject.toml.

``components.body._servo``, the arm plant's sub-step loop (components/body/_servo.c): built without FMA contraction or
fast math, so its arithmetic is numpy's to the bit, and optional: where it does not build (no C compiler) the install
goes on with a warning and the plant runs its numpy loop.
"""
from setuptools import Extension, setup

setup(ext_modules=[Extension("components.body._servo", ["components/body/_servo.c"], optional=True,
                             extra_compile_args=["-ffp-contract=off", "-fno-fast-math"])])
