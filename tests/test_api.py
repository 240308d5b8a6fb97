"""`import rhi`: one top-level name, a light import, the one-call API from a script without a main guard, and
results as data frames and arrays equal to the files the command line writes."""
import doctest
import os
import subprocess
import sys
import sysconfig
import textwrap
from importlib import metadata
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import rhi
import rhi.api


def test_the_distribution_installs_the_one_top_level_name_rhi():
    # the installed distribution's record in site-packages (not the build's rhi.egg-info beside the sources)
    found = list(Path(sysconfig.get_paths()["purelib"]).glob("rhi-*.dist-info"))
    assert len(found) == 1, found
    distribution = metadata.Distribution.at(found[0])
    assert distribution.read_text("top_level.txt").split() == ["rhi"]
    tops = {file.parts[0] for file in distribution.files or ()
            if not str(file).startswith(("rhi-", "__editable__", "../"))}
    assert tops <= {"rhi", "__pycache__"}, tops


def test_import_rhi_is_light():
    done = subprocess.run([sys.executable, "-c", "import sys, rhi; rhi.models; print(sorted(m for m in "
                           "('torch', 'pandas', 'matplotlib', 'distributed') if m in sys.modules))"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "[]", done.stderr[-2000:]


@pytest.mark.parametrize("module", [rhi, rhi.api])
def test_doctests(module):
    failed, tried = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert tried > 0 and failed == 0


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'run_experimnet'"):
        rhi.run_experimnet  # noqa: B018


@pytest.fixture(scope="module")
def tiny(quick_cache, tmp_path_factory):
    """A tiny run from a script with no main guard, in a child process with a time limit (as a user runs it):
    the script writes its result's folder and its tables as the API gives them."""
    folder = tmp_path_factory.mktemp("script")
    script = folder / "tiny.py"
    script.write_text(textwrap.dedent("""
        import pickle, sys
        import rhi
        r = rhi.run_experiment(trials=1, steps=30)
        print(r.summary.shape)
        r.write(sys.argv[1])
        pickle.dump((r.summary, r.trials, r.per_step, r.result.per_step), open(sys.argv[2], "wb"))
        """))
    done = subprocess.run([sys.executable, str(script), str(folder / "out"), str(folder / "frames.pkl")],
                          capture_output=True, text=True, timeout=400, cwd=folder,
                          env={**os.environ, "RHI_CACHE": str(quick_cache)})
    assert done.returncode == 0, done.stderr[-3000:]
    import pickle
    return folder, done.stdout, pickle.loads((folder / "frames.pkl").read_bytes())


def test_a_script_without_a_main_guard_runs_and_returns_frames(tiny):
    folder, stdout, (summary, trials, per_step, arrays) = tiny
    # 2 decoders x 3 conditions x 2 stimulations, one row each
    assert stdout.splitlines()[0].startswith("(12, ")
    assert isinstance(summary, pd.DataFrame) and isinstance(trials, pd.DataFrame)
    assert len(trials) == 12 * 31  # a row per trial and step: 30 steps and the start
    assert str(trials["condition"].dtype) == "category" and trials["seed"].dtype == np.int64


def test_the_frames_equal_the_files_the_command_line_writes(tiny):
    folder, _, (summary, trials, per_step, arrays) = tiny
    pd.testing.assert_frame_equal(summary, pd.read_csv(folder / "out" / "summary.csv"), check_dtype=False,
                                  check_categorical=False)
    pd.testing.assert_frame_equal(trials, pd.read_csv(folder / "out" / "trials.csv"), check_dtype=False,
                                  check_categorical=False)


def test_per_step_holds_the_unrounded_arrays_trial_by_time(tiny):
    _, _, (summary, trials, per_step, arrays) = tiny
    assert per_step.sizes == {"trial": 12, "time_s": 31}
    for key, values in arrays.items():
        assert np.array_equal(per_step[key].values, np.asarray(values).T, equal_nan=True), key
    assert set(per_step["condition"].values) == {"left", "center", "right"}
    # trials.csv rounds to %.6g: the Dataset's values agree with the frame's to that rounding (6 digits)
    drift = trials.pivot_table(index=["decoder", "condition", "stimulation"], columns="step", values="drift_cm",
                               observed=True)
    assert np.allclose(np.sort(drift.values.ravel()), np.sort(per_step["drift_cm"].values.ravel()), rtol=1e-5,
                       atol=1e-12)


def test_config_and_keywords_together_are_refused():
    with pytest.raises(ValueError, match="either config or the keywords"):
        rhi.run_experiment(rhi.load_config(quick=True), trials=1)


@pytest.mark.parametrize("source, guarded", [
    ("import rhi\nrhi.run_experiment()\n", False),
    ("import rhi\n\ndef main():\n    rhi.run_experiment()\n\nif __name__ == '__main__':\n    main()\n", True),
    ("import rhi\nif __name__ == \"__main__\":\n    rhi.run_experiment()\n", True),
    ("import rhi\nif True:\n    rhi.run_experiment()\n", False),
])
def test_workers_are_spawned_only_from_a_script_with_a_main_guard(tmp_path, monkeypatch, source, guarded):
    from types import ModuleType

    from rhi.master.runtime import pool

    script = tmp_path / "script.py"
    script.write_text(source)
    main = ModuleType("__main__")
    main.__file__, main.__spec__ = str(script), None
    monkeypatch.setitem(sys.modules, "__main__", main)
    assert pool.main_module_guarded() is guarded
    del main.__file__  # a notebook, a shell, python -c: nothing of the user's to import again
    assert pool.main_module_guarded() is True


def test_a_local_cluster_from_an_unguarded_script_is_refused_in_one_line(monkeypatch):
    from rhi.master.cosim import ConfigError
    from rhi.master.runtime import pool
    from rhi.master.sweeps.runner import dask_client

    monkeypatch.setattr(pool, "main_module_guarded", lambda: False)
    with pytest.raises(ConfigError, match='if __name__ == "__main__":'):
        with dask_client(None, 1, False):
            pass


def test_a_sweep_runs_in_memory_as_a_frame_a_row_per_trial(tmp_path, monkeypatch, quick_cache):
    """rhi.run_sweep: a row per trial with its point's values beside its record; the points' values reach the
    trials (gamma0's prior changes the drift: the paper's eq. 9 weighs vision by it)."""
    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    path = tmp_path / "sweep.toml"
    path.write_text('[experiment]\ndecoders = ["conv"]\nconditions = ["left"]\nstimulations = ["sync"]\nsteps = 20\n'
                    '[sweep]\nquick = true\ntrials = 1\n[sweep.grid]\n"brain.gamma0" = [0.01, 0.9]\n')
    sweep = rhi.load_sweep(path)
    frame = rhi.run_sweep(sweep)
    assert isinstance(frame, pd.DataFrame) and len(frame) == len(sweep.trials) == 2
    assert sorted(frame["brain.gamma0"]) == [0.01, 0.9]
    assert list(frame["point"]) == [sweep.points.index({"brain.gamma0": g}) for g in frame["brain.gamma0"]]
    drift = dict(zip(frame["brain.gamma0"], frame["drift_cm"]))
    assert drift[0.01] != drift[0.9]


def test_per_step_nc_reads_back_as_the_dataset_bit_for_bit(tiny):
    """The folder's per_step.nc, opened by xarray, is ``r.per_step``: the same values to the bit (NetCDF-4 keeps
    float64 and int64 as they are), dims, coordinates and attributes."""
    import xarray as xr

    folder, _, (summary, trials, per_step, arrays) = tiny
    with xr.open_dataset(folder / "out" / "per_step.nc", engine="h5netcdf") as stored:
        xr.testing.assert_identical(stored.load(), per_step)
        assert stored["seed"].dtype == np.int64
