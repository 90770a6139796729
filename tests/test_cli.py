"""The command line and the progress bar."""

import io

from lieseries.cli import main
from lieseries.progress import ProgressBar
from lieseries.scenes import builtin_scenes


def test_scenes_lists_the_builtins(capsys):
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    lines = out.strip().splitlines()
    assert lines[0].startswith("default ")
    for name, title in builtin_scenes():
        assert any(line.startswith(name + " ") and title in line for line in lines), name


def test_run_default_quick(tmp_path, capsys):
    out_dir = tmp_path / "rep"
    assert main(["run", "default", "--out", str(out_dir), "--quick", "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert (out_dir / "report.md").is_file()
    assert str(out_dir / "report.md") in captured.out
    assert "heyoka double" in captured.out and "final error" in captured.out
    assert captured.err == ""  # --no-progress: nothing on stderr


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
