"""The command line and the progress bar."""

import io
import math
import subprocess
import sys
import warnings

import pytest

from lieseries.cli import main
from lieseries.progress import ProgressBar
from lieseries.scenes import builtin_scenes
from problems import as_from_a_terminal


def test_scenes_lists_the_builtins(capsys):
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    lines = out.strip().splitlines()
    assert lines[0].startswith("default ")
    for name, title in builtin_scenes():
        assert any(line.startswith(name + " ") and title in line for line in lines), name


def scene_file(tmp_path, name="mine", t="1"):
    path = tmp_path / f"{name.replace('/', '_')}.toml"
    path.write_text(
        f'name = "{name}"\ntitle = "a file"\n[model]\nkind = "sphere_dirac"\n[initial]\nx = [1, 0, 0]\n'
        f'v = [0, 1, 0]\n[run]\nt = {t}\nmethods = [{{ method = "taylor" }}]\n'
    )
    return path


@pytest.mark.parametrize("name, t, says", [
    ("../../x", "1", "`name` must be a name"),
    ("/tmp/x", "1", "`name` must be a name"),
    ("ok", '"1e99999999"', "`run.t`"),
    ("ok", '"1e400"', "`run.t`"),
    ("ok", '"1/0"', "`run.t`"),
    ("ok", "1e400", "`run.t`"),
])
def test_bad_scene_values_exit_2_with_one_line(tmp_path, capsys, name, t, says):
    assert main(["run", str(scene_file(tmp_path, name, t)), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert says in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_run_exit_status_and_overwrite(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    scene = str(scene_file(tmp_path))
    assert main(["run", scene, "--out", str(out), "--no-progress"]) == 2  # a folder with the user's files
    assert main(["run", scene, "--out", str(out), "--no-progress", "--overwrite"]) == 0
    assert (out / "notes.txt").read_text() == "mine" and (out / "report.md").is_file()
    assert main(["run", scene, "--out", str(out), "--no-progress", "--overwrite"]) == 0  # again: its own files
    # a run that ends without success exits 1 (the damped stiff body stops with step_collapse)
    stiff = tmp_path / "stiff.toml"
    stiff.write_text('name = "stiff"\ntitle = "t"\n[model]\nkind = "damped_euler_poisson"\n'
                     'inertia = [1, 2, 3]\ndamping = 100000\n[initial]\nomega = [1, "0.1", "0.5"]\n[run]\nt = 20\n'
                     'methods = [{ method = "taylor" }]\n')
    assert main(["run", str(stiff), "--out", str(tmp_path / "s"), "--no-progress"]) == 1
    assert "step_collapse" in capsys.readouterr().out
    # so does a failed study: the same body in a work-precision study only (no [run] table: the study's 256-bit
    # reference cannot pass the stiffness), and the report is still written
    wp = tmp_path / "wp.toml"
    wp.write_text('name = "wp"\ntitle = "t"\n[model]\nkind = "damped_euler_poisson"\ninertia = [1, 2, 3]\n'
                  'damping = 100000\n[initial]\nomega = [1, "0.1", "0.5"]\n'
                  '[studies.work_precision]\nt = 20\nrepeat = 1\n'
                  'methods = [{ method = "taylor", precision = "double", tol = [1e-10] }]\n')
    assert main(["run", str(wp), "--out", str(tmp_path / "w"), "--no-progress"]) == 1
    assert "work precision: RuntimeError" in (tmp_path / "w" / "report.md").read_text()
    said = capsys.readouterr().out
    assert "not every run succeeded" in said and "work precision: RuntimeError" in said and "stiff" in said


def test_run_scene_file_path(tmp_path, capsys):
    scene = tmp_path / "mine.toml"
    scene.write_text(
        'name = "mine"\ntitle = "a file"\n[model]\nkind = "sphere_dirac"\n[initial]\nx = [1, 0, 0]\n'
        'v = [0, 1, 0]\n[run]\nt = 1\nmethods = [{ method = "taylor" }]\n'
    )
    assert main(["run", str(scene), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    assert "report:" in capsys.readouterr().out
    assert (tmp_path / "out" / "report.md").is_file()


def test_bad_scene_path_exits_2_with_one_line(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.toml"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "not found" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_invalid_scene_exits_2_naming_the_field(tmp_path, capsys):
    scene = tmp_path / "bad.toml"
    scene.write_text('name = "b"\ntitle = "b"\n[model]\nkind = "euler_poisson"\ninertia = "abc"\n'
                     '[initial]\nomega = [1, 0, 0]\n[run]\nt = 1\nmethods = [{ method = "taylor" }]\n')
    assert main(["run", str(scene)]) == 2
    err = capsys.readouterr().err
    assert "`model.inertia`" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_unknown_scene_name_and_usage_errors(capsys):
    assert main(["run", "no-such-scene"]) == 2
    err = capsys.readouterr().err
    assert "unknown scene 'no-such-scene'" in err and "default" in err
    assert main(["run"]) == 2
    assert "required: SCENE" in capsys.readouterr().err
    assert main(["frobnicate"]) == 2
    assert main([]) == 2


def test_progress_bar_silent_off_tty_and_drawn_when_forced():
    quiet = io.StringIO()
    bar = ProgressBar("x", stream=quiet)
    for i in range(5):
        bar(i + 1, 5, "step")
    bar.close()
    assert quiet.getvalue() == ""  # StringIO is not a TTY: nothing, so CI logs stay clean

    loud = io.StringIO()
    bar = ProgressBar("study", stream=loud, enabled=True, min_interval=0.0)
    bar(1, 4, "one")
    bar(4, 4, "done")
    text = loud.getvalue()
    assert "\r" in text and "study" in text and "4/4" in text and "done" in text
    bar.close()


def test_progress_env_switch(monkeypatch):
    tty = io.StringIO()
    tty.isatty = lambda: True
    monkeypatch.delenv("LIESERIES_PROGRESS", raising=False)
    monkeypatch.setenv("CI", "true")
    assert not ProgressBar(stream=tty).enabled  # silent in CI, even on a terminal
    monkeypatch.delenv("CI")
    assert ProgressBar(stream=tty).enabled
    monkeypatch.setenv("LIESERIES_PROGRESS", "1")
    assert ProgressBar(stream=io.StringIO()).enabled
    monkeypatch.setenv("LIESERIES_PROGRESS", "0")
    assert not ProgressBar(stream=io.StringIO()).enabled


def test_validation_scripts_run_a_scene_into_a_folder(tmp_path, capsys):
    """`make validate` is validation/run_all.py: one quick scene into a fresh folder, exit 0, its report written.
    (Its main() in this process: the script's own lines are what is tested, `python -m` has its test above.)"""
    import importlib.util

    spec = importlib.util.spec_from_file_location("run_all", ROOT / "validation" / "run_all.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.main(["default", "--quick", "--no-progress", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "default" / "report.md").is_file()
    assert str(tmp_path / "default") in out and "1/1 scenes done" in out


def test_a_quick_report_says_which_settings_it_changed(tmp_path, capsys):
    """Quick mode runs the certified-digits scene at 30 digits to t = 2: the report must not let the scene's
    title (50 digits, T = 10) stand for what was run."""
    assert main(["run", "certified-digits", "--quick", "--out", str(tmp_path / "q"), "--no-progress"]) == 0
    text = (tmp_path / "q" / "report.md").read_text()
    assert "- `run.methods[0].dps: 50 -> 30`" in text and "- `run.t: 10 -> 2`" in text
    assert "validated (Arb) 30 dps" in text and "validated (Arb) 50 dps" not in text


# -- what a plain install needs ---------------------------------------------------------------------------------
ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("module", ["scipy", "matplotlib"])
def test_a_missing_package_is_named_before_any_computation(tmp_path, capsys, monkeypatch, module):
    """Without scipy (or matplotlib) `lieseries run default` used to compute, then exit 1 with a traceback."""
    from lieseries import run as run_module

    monkeypatch.setitem(sys.modules, module, None)  # what `import scipy` meets where it is not installed
    monkeypatch.setattr(run_module, "run_scene", lambda *a, **k: pytest.fail("the scene was computed"))
    assert main(["run", "default", "--no-progress", "--out", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err
    assert f"`{module}`" in err and "pip install" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "rep").exists()  # refused before the folder was taken and before computing


def test_the_command_line_starts_without_scipy_and_matplotlib(tmp_path):
    """The package imports without them, so `lieseries run` can name both (exit 2, one line) in a fresh process."""
    import os

    code = ("import sys; sys.modules['scipy'] = sys.modules['matplotlib'] = None\n"
            "import lieseries.cli as c; sys.exit(c.main(sys.argv[1:]))")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", code, "run", "default", "--no-progress", "--out",
                          str(tmp_path / "rep")], capture_output=True, text=True, timeout=300, env=env)
    assert res.returncode == 2, res.stderr
    assert "`scipy`" in res.stderr and "`matplotlib`" in res.stderr and "pip install" in res.stderr
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "rep").exists()


def test_environment_says_not_installed_for_a_missing_package(monkeypatch):
    from lieseries.run import environment

    monkeypatch.setitem(sys.modules, "scipy", None)
    env = environment()
    assert env["scipy"] == "not installed"
    import numpy

    assert env["numpy"] == numpy.__version__


def test_a_plain_install_brings_what_the_command_line_needs():
    """`pip install lieseries` with no extras must run `lieseries run default`: the packages the command line
    checks for are ordinary dependencies."""
    import re
    import tomllib

    from lieseries.cli import RUN_REQUIREMENTS

    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    names = {re.match(r"[A-Za-z0-9_.-]+", d).group(0).lower() for d in deps}
    assert {"scipy", "matplotlib"} <= {m for m, _, _ in RUN_REQUIREMENTS} <= names


@pytest.mark.parametrize("read_lines", [0, 1])
def test_a_closed_pipe_is_not_an_error(read_lines):
    """`lieseries scenes | head -1`: the reader goes away; no "[Errno 32] Broken pipe", no traceback, status 0."""
    import os

    # the child writes nothing before its stdin ends: without lines to read, the reader is gone before the first
    code = "import sys; import lieseries.cli as c; sys.stdin.read(); sys.exit(c.main(sys.argv[1:]))"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-c", code, "scenes"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, env=env, cwd=str(ROOT))
    if not read_lines:
        p.stdout.close()
    p.stdin.close()
    for _ in range(read_lines):
        assert p.stdout.readline().startswith(b"default ")
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 0, err
    assert "Broken pipe" not in err and "Traceback" not in err and "Exception ignored" not in err


def test_the_console_table_says_where_a_capped_run_stopped(tmp_path, capsys):
    """mpmath's odefun capped by t_max = 1 in a T = 3 table: its `success` is at t = 1, and the table says so."""
    scene = tmp_path / "capped.toml"
    scene.write_text('name = "capped"\ntitle = "t"\n[model]\nkind = "sphere_dirac"\n[initial]\nx = [1, 0, 0]\n'
                     'v = [0, 1, 0]\n[run]\nt = 3\nmethods = [{ method = "taylor" }, '
                     '{ method = "mpmath", dps = 15, t_max = 1 }]\n')
    assert main(["run", str(scene), "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    out = capsys.readouterr().out.splitlines()
    header = next(line for line in out if line.startswith("method"))
    col = header.index("t reached")
    rows = {line[:col].strip(): line[col:].split()[0] for line in out
            if line.startswith(("heyoka double", "mpmath odefun")) and "ran to" not in line}
    assert rows == {"heyoka double": "3", "mpmath odefun 15 dps": "1"}
    assert any(line.startswith("mpmath odefun 15 dps: ran to t = 1 only, not t = 3") for line in out)


def test_a_folder_given_as_the_scene_is_called_a_folder(tmp_path, capsys):
    assert main(["run", str(tmp_path), "--no-progress", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"`{tmp_path}` is a folder, not a scene file" in err and ".toml" in err and "not found" not in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


#: Put on PYTHONPATH as sitecustomize: Ctrl-C (SIGINT to itself) the moment `module` starts to import.
CTRL_C_AT_IMPORT = """
import os, signal, sys

class CtrlC:
    fired = False

    def find_spec(self, name, path=None, target=None):
        if name == {module!r} and not CtrlC.fired:
            CtrlC.fired = True
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.meta_path.insert(0, CtrlC())
"""


@pytest.mark.parametrize("module", ["heyoka", "sympy", "scipy"])
def test_ctrl_c_while_the_command_line_imports_exits_130_without_a_traceback(tmp_path, module):
    """Ctrl-C while heyoka's or sympy's extension initialises surfaced as ImportError or AttributeError, exit 1.
    Run as `python -m lieseries`, the command line for when the console script is not on PATH: main()'s status and
    its one line reach the shell (main()'s other statuses are tested in this process)."""
    import os

    (tmp_path / "sitecustomize.py").write_text(CTRL_C_AT_IMPORT.format(module=module))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}
    res = subprocess.run([sys.executable, "-m", "lieseries", "run", "default", "--no-progress", "--out",
                          str(tmp_path / "rep")], capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path,
                         preexec_fn=as_from_a_terminal)
    assert res.returncode == 130, res.stderr
    assert res.stderr.strip() == "lieseries: interrupted"
    assert not (tmp_path / "rep").exists()


def test_ctrl_c_while_the_library_imports_is_a_keyboard_interrupt(tmp_path):
    import os

    (tmp_path / "sitecustomize.py").write_text(CTRL_C_AT_IMPORT.format(module="heyoka"))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}
    # one process: the import raises KeyboardInterrupt, and Ctrl-C is itself again afterwards (the handler was
    # restored) and the package imports on a second try
    code = "try:\n    import lieseries\nexcept KeyboardInterrupt:\n    print('interrupted')\n"
    code += "import signal\nassert signal.getsignal(signal.SIGINT) is signal.default_int_handler\n"
    code += "import lieseries\nprint(lieseries.integrate.__name__)\n"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env,
                         cwd=tmp_path, preexec_fn=as_from_a_terminal)
    assert res.returncode == 0 and res.stdout.split() == ["interrupted", "integrate"], res.stderr


def test_a_quick_run_does_not_let_a_methods_own_label_claim_digits_it_did_not_use(tmp_path, capsys):
    """`label = "Arb 50 digits"` on a validated method: quick mode runs it at 30 digits, and says so beside it."""
    scene = tmp_path / "arb.toml"
    scene.write_text('name = "arb"\ntitle = "t"\n[model]\nkind = "euler_poisson"\ninertia = [1, 2, 3]\n'
                     '[initial]\nomega = [1, "0.1", "0.5"]\n[run]\nt = "1/4"\nsamples = 2\n'
                     'methods = [{ method = "validated", dps = 50, label = "Arb 50 digits" }]\n')
    assert main(["run", str(scene), "--quick", "--out", str(tmp_path / "q"), "--no-progress"]) == 0
    said = capsys.readouterr().out
    md = (tmp_path / "q" / "report.md").read_text()
    row = next(line for line in md.splitlines() if line.startswith("| Arb 50 digits"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[0] == "Arb 50 digits (quick mode: dps = 30)" and cells[1] == "30 dps"
    assert "Arb 50 digits (quick mode: dps = 30)" in said
    # the full run keeps the label as it is
    assert main(["run", str(scene), "--out", str(tmp_path / "f"), "--no-progress"]) == 0
    md = (tmp_path / "f" / "report.md").read_text()
    row = next(line for line in md.splitlines() if line.startswith("| Arb 50 digits"))
    assert [c.strip() for c in row.strip("|").split("|")][:2] == ["Arb 50 digits", "50 dps"]


# -- estimates of long scenes, and --max-time ---------------------------------------------------------------------
LONG_SCENE = ('name = "long"\ntitle = "many samples at many digits"\n[model]\nkind = "euler_poisson"\n'
              'inertia = [1, 2, 3]\n[initial]\nomega = [1, "0.1", "0.5"]\n[run]\nt = 20\nsamples = 100000\n'
              'methods = [{ method = "lie", dps = 250 }]\n')


def test_a_scene_estimated_beyond_max_time_is_refused_before_computing(tmp_path, capsys, monkeypatch):
    """samples = 100000 with a Lie method at 250 digits (estimated at 97 s): refused with exit 2, naming the
    field that drives it and the estimate, and nothing is computed or written."""
    from lieseries import run as run_module

    monkeypatch.setattr(run_module, "run_scene", lambda *a, **k: pytest.fail("the scene was computed"))
    scene = tmp_path / "long.toml"
    scene.write_text(LONG_SCENE)
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out), "--max-time", "30", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "`run.samples`" in err and "--max-time 30 s" in err and "estimated" in err
    assert "99999 sample intervals x lie dps 250" in err  # 100000 sample times, t = 0 among them
    assert not out.exists()  # the folder it created for the report is gone again: nothing was written


def test_max_time_must_be_a_positive_number_of_seconds(tmp_path, capsys):
    for bad in ("0", "-3", "soon", "inf"):
        assert main(["run", "default", "--out", str(tmp_path / "x"), "--max-time", bad]) == 2
        assert "--max-time" in capsys.readouterr().err


def test_the_estimate_counts_the_scenes_units_exactly():
    from lieseries.cost import estimate_scene
    from lieseries.scenes import parse_scene

    text = ('name = "count"\ntitle = "c"\n[model]\nkind = "euler_poisson"\ninertia = [1, 2, 3]\n[initial]\n'
            'omega = [1, "0.1", "0.5"]\n[run]\nt = 2\nsamples = 21\nrepeat = 1\n'
            'methods = [{ method = "lie", dps = 20 }, { method = "taylor" }]\n'
            '[studies.departure_map]\ngrid = [2, 3]\nT = 4\nsamples = 5\nprecisions = ["double", "quad"]\n')
    est = estimate_scene(parse_scene(text))
    units = {p.what.split(" at ")[0] if "measured" in p.what else p.what: p.units for p in est.parts}
    assert units == {"20 sample intervals x lie dps 20": 20, "20 sample intervals x taylor double": 20,
                     "20 output times measured": 20,
                     "6 cells x 5 closed-form times at 45 digits": 30,
                     "6 members to T = 4 in double": 6, "6 members to T = 4 in quad": 6}
    assert all(math.isfinite(p.seconds_each) and p.seconds_each > 0 for p in est.parts)
    assert 0 < est.seconds < math.inf and est.calibration_seconds < 10
    assert est.summary().startswith("estimated ")


@pytest.mark.slow  # runs the scene to compare (a few seconds)
def test_a_small_scenes_estimate_is_within_a_factor_of_five_of_its_run_time():
    import time

    from lieseries.cost import estimate_scene
    from lieseries.run import run_scene
    from lieseries.scenes import parse_scene

    scene = parse_scene('name = "small"\ntitle = "s"\n[model]\nkind = "euler_poisson"\ninertia = [1, 2, 3]\n'
                        '[initial]\nomega = [1, "0.1", "0.5"]\n[run]\nt = 4\nsamples = 41\nrepeat = 1\n'
                        'methods = [{ method = "lie", dps = 40 }, { method = "validated", dps = 20 }]\n')
    est = estimate_scene(scene).seconds
    start = time.perf_counter()
    run_scene(scene, progress=False)
    real = time.perf_counter() - start
    assert real / 5 < est < real * 5, (est, real)


def test_run_scene_refuses_a_scene_beyond_max_time():
    from lieseries.cost import SceneTooLong
    from lieseries.run import run_scene
    from lieseries.scenes import parse_scene

    with pytest.raises(SceneTooLong, match=r"`max_time` 30 s.*`run.samples`"):
        run_scene(parse_scene(LONG_SCENE), progress=False, max_time=30)


def test_a_long_estimate_is_printed_before_computing(tmp_path, capsys, monkeypatch):
    from lieseries import cost

    monkeypatch.setattr(cost, "PRINT_ABOVE", 0.0)  # every scene counts as long
    scene = tmp_path / "s.toml"
    scene.write_text(LONG_SCENE.replace("samples = 100000", "samples = 3").replace("t = 20", "t = '0.1'")
                     .replace("dps = 250", "dps = 20"))
    assert main(["run", str(scene), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("lieseries: estimated ") and "6 sample intervals x lie dps 20" in err  # 2 x 3 repeats


def test_a_part_that_cannot_be_priced_leaves_a_lower_bound_not_an_error(monkeypatch):
    from lieseries import cost

    def fails(*args, **kwargs):
        raise RuntimeError("calibration failed")

    from lieseries.studies.plugin import study_plugin

    monkeypatch.setattr(study_plugin("departure_map"), "cost", fails)  # the study prices itself
    est = cost.estimate_scene("departure-map", quick=True)
    assert est.lower_bound and est.summary().startswith("estimated at least ")
    assert any("not estimated (RuntimeError: calibration failed)" in p.what for p in est.parts)


def test_run_warns_of_a_binary_scene_number_once(tmp_path, recwarn):
    """A binary float in a scene feeds every run at its own precision: one PrecisionWarning per number and CLI
    invocation (not one per run, differing only in the bits), naming the scene field and what to write."""
    from lieseries.precision import PrecisionWarning

    path = tmp_path / "binary.toml"
    path.write_text(
        'name = "binary"\ntitle = "a file"\n[model]\nkind = "sphere_dirac"\n[initial]\nx = [0.6, 0.8, 0]\n'
        'v = [0, 0, 1]\n[run]\nt = 1\nmethods = [{ method = "taylor", precision = "double" }, '
        '{ method = "taylor", precision = "quad" }, { method = "lie", dps = 20 }]\n'
    )
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--no-progress", "--quick"]) == 0
    found = [str(w.message) for w in recwarn if issubclass(w.category, PrecisionWarning)]
    assert len(found) == 1, found
    assert "up to 113 bits" in found[0] and "write `initial.x[0]`, `initial.x[1]` as strings" in found[0], found[0]


def test_scenes_in_two_threads_keep_the_process_warnings():
    """run_scene gathers its runs' warnings through Python's one capture per process: two scenes that overlapped in
    threads restored each other's capture, and every later warning of the process went to a finished scene's list,
    never shown. Scenes now run one at a time; both give their results and the warnings after them are seen."""
    import threading

    from lieseries.run import run_scene
    from lieseries.scenes import parse_scene

    text = ('name = "x"\ntitle = "x"\ndescription = "x"\n[model]\nkind = "sphere_dirac"\n[initial]\n'
            'x = [0.6, 0.8, 0]\nv = [0, 0, 1]\n[run]\nt = "0.5"\nmethods = [{ method = "taylor", precision = "double" }]\n')
    results = []
    shown, filters = warnings.showwarning, list(warnings.filters)
    threads = [threading.Thread(target=lambda: results.append(run_scene(parse_scene(text), quick=True,
                                                                          progress=False))) for _ in range(2)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert len(results) == 2 and all(row.status == "success" for r in results for row in r.run["rows"])
    assert warnings.showwarning is shown and warnings.filters == filters
