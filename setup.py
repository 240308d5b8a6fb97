"""The package's layout and its C part; everything else is in pyproject.toml.

The distribution installs one top-level name, ``rhi``. The repository keeps the design's layout: ``components/``
and ``master/`` at the top, installed as ``rhi.components`` and ``rhi.master``; ``rhi/`` holds the public API.

Two optional C extensions, built without FMA contraction or fast math so that their arithmetic is numpy's to the
bit; where one does not build (no C compiler) the install goes on with a warning and its numpy loop runs instead:
``rhi.components.body._servo``, the arm plant's sub-step loop (components/body/_servo.c), and
``rhi.components.body._arm``, the batched arm's sub-steps (components/body/_arm.c).
"""
from setuptools import Extension, find_packages, setup

FOLDERS = ("components", "master")  # installed under rhi
PACKAGES = ["rhi"] + [f"rhi.{name}" for name in find_packages(include=[f"{folder}*" for folder in FOLDERS])]
EXACT = ["-ffp-contract=off", "-fno-fast-math"]

setup(packages=PACKAGES, package_dir={"rhi": "rhi", **{f"rhi.{folder}": folder for folder in FOLDERS}},
      ext_modules=[Extension("rhi.components.body._servo", ["components/body/_servo.c"], optional=True,
                             extra_compile_args=EXACT),
                   Extension("rhi.components.body._arm", ["components/body/_arm.c"], optional=True,
                             extra_compile_args=EXACT)])
