"""The report folder: lieseries replaces only files it can prove it wrote, never follows a symbolic link, holds
the folder for one run at a time and moves a report into place only when it is whole."""

import contextlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from lieseries import folder as fold
from lieseries import report as rep
from lieseries.cli import main
from lieseries.folder import LOCK, MANIFEST, FolderError, ReportFolder
from lieseries.report import write_report
from lieseries.run import run_scene
from lieseries.scenes import parse_scene
from problems import as_from_a_terminal

ROOT = Path(__file__).resolve().parents[1]

SCENE = ('name = "mine"\ntitle = "a sphere"\n[model]\nkind = "sphere_dirac"\n[initial]\nx = [1, 0, 0]\n'
         'v = [0, 1, 0]\n[run]\nt = 1\nsamples = 5\nmethods = [{ method = "taylor" }]\n')


@pytest.fixture(scope="module")
def result():
    return run_scene(parse_scene(SCENE + '[report]\nplots = ["trajectory"]\n'), progress=False)


@pytest.fixture(scope="module")
def longer_result():
    """The scene with the plot, run to t = 2: other numbers, another plot."""
    return run_scene(parse_scene(SCENE.replace("t = 1", "t = 2") + '[report]\nplots = ["trajectory"]\n'),
                     progress=False)


@pytest.fixture(scope="module")
def plain_result():
    """The same scene without plots (no PNG: its report is quick to write)."""
    return run_scene(parse_scene(SCENE), progress=False)


def scene_file(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text(SCENE)
    return str(path)


def snapshot(folder: Path) -> dict:
    """Every entry of ``folder`` (recursively, links not followed): file bytes, or the target of a link."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        if p.is_symlink():
            out[rel] = ("link", os.readlink(p))
        elif p.is_file():
            out[rel] = p.read_bytes()
    return out


def manifest(folder: Path) -> dict:
    return json.loads((folder / MANIFEST).read_text())["files"]


# -- 1. a manifest names only plain files inside the folder ------------------------------------------------------
@pytest.mark.parametrize("entry", ["../victim.txt", "ABS", "sub/../../victim.txt", "./../victim.txt"])
@pytest.mark.parametrize("form", ["names", "hashes"])
def test_a_manifest_naming_a_file_outside_the_folder_is_refused_and_nothing_is_deleted(tmp_path, capsys, entry,
                                                                                         form):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "out"
    out.mkdir()
    entry = str(victim) if entry == "ABS" else entry
    files = [entry] if form == "names" else {entry: "0" * 64}
    (out / MANIFEST).write_text(json.dumps({"files": files}))
    for extra in ([], ["--overwrite"]):
        assert main(["run", scene_file(tmp_path), "--out", str(out), "--no-progress"] + extra) == 2
        err = capsys.readouterr().err
        assert f"`{entry}`" in err and MANIFEST in err and len(err.strip().splitlines()) == 1
        assert victim.read_text() == "precious"
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST]  # nothing written, nothing deleted


def test_a_manifest_that_is_a_link_or_garbage_is_refused(tmp_path, plain_result):
    out = tmp_path / "out"
    out.mkdir()
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"files": {}}))
    (out / MANIFEST).symlink_to(other)
    with pytest.raises(FolderError, match="not a regular file"):
        write_report(plain_result, out, overwrite=True)
    (out / MANIFEST).unlink()
    (out / MANIFEST).write_text("{not json")
    with pytest.raises(FolderError, match="not a manifest"):
        write_report(plain_result, out, overwrite=True)
    assert other.read_text() == json.dumps({"files": {}})


# -- 2. --overwrite never replaces a user's file ---------------------------------------------------------------
def test_overwrite_keeps_the_users_report_and_data_and_says_so(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.md").write_text("my notes")
    (out / "data.json").write_text("[1, 2]")
    assert main(["run", scene_file(tmp_path), "--out", str(out), "--no-progress", "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "`data.json`" in err and "`report.md`" in err and len(err.strip().splitlines()) == 1
    assert (out / "report.md").read_text() == "my notes" and (out / "data.json").read_text() == "[1, 2]"
    assert sorted(p.name for p in out.iterdir()) == ["data.json", "report.md"]


def test_a_report_file_the_user_changed_is_no_longer_lieseries_own(tmp_path, plain_result):
    write_report(plain_result, tmp_path)
    ours = manifest(tmp_path)
    assert set(ours) == {"report.md", "data.json", "run.csv", "run_invariants.csv"}
    (tmp_path / "report.md").write_text("edited by hand")
    for overwrite in (False, True):
        with pytest.raises(FolderError, match="report.md"):
            write_report(plain_result, tmp_path, overwrite=overwrite)
    assert (tmp_path / "report.md").read_text() == "edited by hand"
    # a manifest of an older lieseries (names, no hashes) proves nothing either
    (tmp_path / "report.md").unlink()
    write_report(plain_result, tmp_path)
    (tmp_path / MANIFEST).write_text(json.dumps({"files": sorted(ours)}))
    before = snapshot(tmp_path)
    with pytest.raises(FolderError, match="older lieseries"):
        write_report(plain_result, tmp_path, overwrite=True)
    assert snapshot(tmp_path) == before


def test_overwrite_writes_beside_the_users_files_and_replaces_only_its_own(tmp_path, result, plain_result):
    (tmp_path / "notes.txt").write_text("mine")
    write_report(result, tmp_path, overwrite=True)
    assert (tmp_path / "trajectory.png").is_file() and "notes.txt" not in manifest(tmp_path)
    write_report(plain_result, tmp_path, overwrite=True)  # its own plot, not written again, goes
    assert not (tmp_path / "trajectory.png").exists()
    assert (tmp_path / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(list(manifest(tmp_path)) + [MANIFEST, "notes.txt"])


# -- 3. never write or delete through a symbolic link -----------------------------------------------------------
@pytest.mark.parametrize("name", ["report.md", "data.json", "run.csv"])
def test_a_link_where_a_report_file_was_is_never_followed(tmp_path, plain_result, name):
    out = tmp_path / "out"
    write_report(plain_result, out)
    target = tmp_path / "elsewhere.txt"
    target.write_text("not yours")
    (out / name).unlink()
    (out / name).symlink_to(target)
    before = snapshot(out)
    for overwrite in (False, True):
        with pytest.raises(FolderError, match=name) as err:
            write_report(plain_result, out, overwrite=overwrite)
        assert target.read_text() == "not yours" and (out / name).is_symlink()
        kept = {k: v for k, v in snapshot(out).items() if not k.startswith(fold.STAGING_PREFIX)}
        assert kept == before
    # report.md and data.json are checked before the computation; a CSV only when the report is written: the
    # new report is then kept beside, in the staging folder the message names
    assert ("kept in" in str(err.value)) == (name == "run.csv")


def test_a_link_named_in_the_manifest_is_not_deleted_through(tmp_path, result, plain_result):
    """An earlier report's plot replaced by a link: the next report (no plot) leaves the link and its target."""
    write_report(result, tmp_path)
    target = tmp_path.parent / f"{tmp_path.name}-target.png"
    target.write_bytes((tmp_path / "trajectory.png").read_bytes())  # the same bytes: the hash would match
    (tmp_path / "trajectory.png").unlink()
    (tmp_path / "trajectory.png").symlink_to(target)
    write_report(plain_result, tmp_path, overwrite=True)
    assert (tmp_path / "trajectory.png").is_symlink() and target.is_file()
    assert "trajectory.png" not in manifest(tmp_path)


# -- 4. one run at a time ----------------------------------------------------------------------------------------
def run_cli(*args, **kw):
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-m", "lieseries", *args], capture_output=True, text=True, timeout=300,
                          env=env, **kw)


def test_a_second_run_into_a_held_folder_is_refused_before_computing(tmp_path):
    out = tmp_path / "X"
    with ReportFolder(out):  # another run holds the folder
        res = run_cli("run", "tennis-racket", "--quick", "--no-progress", "--out", str(out))
        assert res.returncode == 2, res.stderr
        assert f"`{out}`" in res.stderr and "another lieseries run" in res.stderr and f"pid {os.getpid()}" in \
            res.stderr and "Traceback" not in res.stderr
        assert sorted(p.name for p in out.iterdir()) == [LOCK]  # nothing computed, nothing written
    assert not out.exists()  # the holder made the folder and left it empty: gone with the lock


def test_a_lock_left_by_a_dead_run_does_not_block(tmp_path, plain_result):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / LOCK).write_text(f"{dead.pid}\n")
    write_report(plain_result, tmp_path)
    assert not (tmp_path / LOCK).exists() and (tmp_path / "report.md").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(fold.STAGING_PREFIX)]


@pytest.mark.slow
def test_two_runs_started_together_never_mix_their_files(tmp_path):
    out = tmp_path / "X"
    procs = [subprocess.Popen([sys.executable, "-m", "lieseries", "run", name, "--quick", "--no-progress", "--out",
                               str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
             for name in ("tennis-racket", "default")]
    codes = [p.wait(timeout=600) for p in procs]
    assert sorted(codes) in ([0, 0], [0, 2])
    data = json.loads((out / "data.json").read_text())
    md = (out / "report.md").read_text()
    assert f"Scene `{data['scene']['name']}`" in md
    assert set(manifest(out)) == {p.name for p in out.iterdir()} - {MANIFEST}


# -- 5. a report moves into place whole --------------------------------------------------------------------------
def test_an_interrupt_while_writing_leaves_the_earlier_report_untouched(tmp_path, result, longer_result,
                                                                         monkeypatch, capsys):
    write_report(result, tmp_path)
    before = snapshot(tmp_path)
    calls = []

    def interrupted(path, headers, rows):  # the plot is written by now; the tables are next
        calls.append(path)
        raise KeyboardInterrupt

    monkeypatch.setattr(rep.scene_report, "write_csv", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_report(longer_result, tmp_path)
    assert calls and snapshot(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(list(manifest(tmp_path)) + [MANIFEST])
    # the command line says so with status 130, and the next run takes the folder as its own
    scene = tmp_path.parent / f"{tmp_path.name}.toml"
    scene.write_text(SCENE.replace("t = 1", "t = 2") + '[report]\nplots = ["trajectory"]\n')
    assert main(["run", str(scene), "--out", str(tmp_path), "--no-progress"]) == 130
    assert "interrupted" in capsys.readouterr().err and snapshot(tmp_path) == before
    monkeypatch.undo()
    assert main(["run", str(scene), "--out", str(tmp_path), "--no-progress"]) == 0


def test_ctrl_c_during_the_move_waits_until_the_report_is_whole(tmp_path, result, plain_result, monkeypatch):
    write_report(result, tmp_path)
    real = os.replace
    moved = []

    def replace(src, dst):
        if not moved:
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C as the first file moves
        moved.append(dst)
        real(src, dst)

    monkeypatch.setattr(fold.os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        write_report(plain_result, tmp_path)
    monkeypatch.undo()
    assert len(moved) > 2  # every file moved, and the manifest, before the interrupt was raised
    ours = manifest(tmp_path)
    assert set(ours) == {"report.md", "data.json", "run.csv", "run_invariants.csv"}
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(list(ours) + [MANIFEST])
    assert all(fold._sha256(tmp_path / name) == h for name, h in ours.items())
    assert json.loads((tmp_path / "data.json").read_text())["scene"]["plots"] == []


@pytest.mark.slow  # ~9 s: a full CLI run in a subprocess (the default suite has the in-process tests above)
def test_a_sigint_while_writing_exits_130_and_keeps_the_earlier_report(tmp_path):
    """A real Ctrl-C to a real run, in its write phase (the writer is slowed down to make room for it)."""
    out = tmp_path / "X"
    scene = tmp_path / "plot.toml"
    scene.write_text(SCENE + '[report]\nplots = ["trajectory"]\n')
    assert main(["run", str(scene), "--out", str(out), "--no-progress"]) == 0  # the earlier report
    before = snapshot(out)
    scene.write_text(SCENE.replace("t = 1", "t = 2") + '[report]\nplots = ["trajectory"]\n')  # a new plot
    code = ("import sys, time, lieseries.report.scene_report as r, lieseries.cli as c\n"
            "w = r.write_csv\n"
            "def slow(*a):\n"
            "    print('writing', flush=True); time.sleep(60); w(*a)\n"
            "r.write_csv = slow\n"
            "sys.exit(c.main(sys.argv[1:]))\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-c", code, "run", str(scene), "--out", str(out), "--no-progress"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                         preexec_fn=as_from_a_terminal)
    assert p.stdout.readline().strip() == "writing"
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130 and "interrupted" in err and "Traceback" not in err
    assert snapshot(out) == before


def test_ctrl_c_pressed_again_and_again_during_the_move_cannot_cut_the_way_out(tmp_path, result, plain_result,
                                                                                  monkeypatch):
    """On the command line the process ends on the held Ctrl-C: later ones are ignored from then on (the cleanup,
    the message and the exit status 130), while the move itself finishes."""
    from lieseries import interrupts

    write_report(result, tmp_path)
    real = os.replace
    moved = []

    def replace(src, dst):
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C at every move
        moved.append(dst)
        real(src, dst)

    monkeypatch.setattr(fold.os, "replace", replace)
    monkeypatch.setattr(interrupts, "is_command_line", lambda: True)
    try:
        with pytest.raises(KeyboardInterrupt):
            write_report(plain_result, tmp_path)
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        os.kill(os.getpid(), signal.SIGINT)  # ignored: no KeyboardInterrupt
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    monkeypatch.undo()
    ours = manifest(tmp_path)
    assert set(ours) == {"report.md", "data.json", "run.csv", "run_invariants.csv"} and len(moved) > 4
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(list(ours) + [MANIFEST])
    assert all(fold._sha256(tmp_path / name) == h for name, h in ours.items())


@pytest.mark.slow  # ~10 s: a full CLI run in a subprocess
def test_sigints_during_the_final_move_exit_130_with_the_new_report_whole(tmp_path):
    """Real Ctrl-Cs, one after another, to the command line while it moves the report into place (each move is
    slowed down to make room for them): exit status 130, not death by the signal; the new report is whole and the
    manifest true."""
    out = tmp_path / "X"
    scene = tmp_path / "plot.toml"
    scene.write_text(SCENE)
    assert main(["run", str(scene), "--out", str(out), "--no-progress"]) == 0  # the earlier report
    scene.write_text(SCENE.replace("t = 1", "t = 2"))
    code = ("import os, sys, time, lieseries.cli as c\n"
            "real = os.replace\n"
            "def slow(a, b):\n"
            "    print('moving', flush=True); time.sleep(0.3); real(a, b)\n"
            "os.replace = slow\n"
            "sys.argv[0] = 'lieseries'  # the command line, as the console script is\n"
            "sys.exit(c.main(sys.argv[1:]))\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-c", code, "run", str(scene), "--out", str(out), "--no-progress"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                         preexec_fn=as_from_a_terminal)
    assert p.stdout.readline().strip() == "moving"
    for _ in range(40):  # ~2 s of Ctrl-C: through the move, the cleanup and the exit
        if p.poll() is not None:
            break
        p.send_signal(signal.SIGINT)
        with contextlib.suppress(subprocess.TimeoutExpired):
            p.wait(timeout=0.05)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130 and "interrupted" in err and "Traceback" not in err
    ours = manifest(out)
    assert sorted(p.name for p in out.iterdir()) == sorted(list(ours) + [MANIFEST])
    assert all(fold._sha256(out / name) == h for name, h in ours.items())
    assert json.loads((out / "data.json").read_text())["scene"]["run"]["t"] == 2  # the new report


# -- the report's words match the data ---------------------------------------------------------------------------
def test_the_run_section_counts_the_samples_the_scene_asks_for(tmp_path):
    """The default scene's `samples = 101`: 101 sample times, t = 0 and 100 output times (it said 100 only)."""
    import tomllib

    from lieseries.scenes import load_scene

    text = (ROOT / "lieseries" / "data" / "scenes" / "default.toml").read_text()
    setting = tomllib.loads(text)["run"]
    n, t = setting["samples"], setting["t"]
    assert load_scene("default").run["samples"] == n
    # the scene as it is, with its first method only (the others cost time and change nothing here)
    lines = [line for line in text.splitlines()
             if not line.startswith("  { method") or 'precision = "double"' in line]
    res = run_scene(parse_scene("\n".join(lines)), progress=False)
    assert [r.label for r in res.run["rows"]] == ["heyoka double"]
    md = write_report(res, tmp_path).read_text()
    assert f"{n} samples: t = 0 and {n - 1} equally spaced output times (every {t / (n - 1):g})" in md
    traj = next(iter(res.trajectories.values()))
    assert len(traj["times"]) == n and traj["times"][0] == 0 and traj["times"][-1] == t
    assert all(len(ts) == n - 1 for ts in traj["error_times"].values())


# -- folders inside a report (the stability report's scenes/<case>/) --------------------------------------------
def stage_files(folder, files):
    stage = folder.staging()
    for rel, text in files.items():
        (stage / rel).parent.mkdir(parents=True, exist_ok=True)
        (stage / rel).write_text(text)
    folder.commit()


def test_files_in_subfolders_are_replaced_and_removed_like_the_others(tmp_path):
    with ReportFolder(tmp_path) as f:
        stage_files(f, {"report.md": "a", "scenes/one/report.md": "1", "scenes/two/report.md": "2"})
    assert set(manifest(tmp_path)) == {"report.md", "scenes/one/report.md", "scenes/two/report.md"}
    (tmp_path / "scenes" / "two" / "notes.txt").write_text("mine")
    with ReportFolder(tmp_path, overwrite=True) as f:
        stage_files(f, {"report.md": "b", "scenes/one/report.md": "1b"})
    assert snapshot(tmp_path) == {MANIFEST: (tmp_path / MANIFEST).read_bytes(), "report.md": b"b",
                                  "scenes/one/report.md": b"1b", "scenes/two/notes.txt": b"mine"}
    with ReportFolder(tmp_path, overwrite=True) as f:
        stage_files(f, {"report.md": "c"})
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == [
        MANIFEST, "report.md", "scenes", "scenes/two", "scenes/two/notes.txt"]  # emptied folders of ours go


def test_a_linked_subfolder_is_never_written_through(tmp_path):
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    elsewhere.mkdir()
    with ReportFolder(out) as f:
        stage_files(f, {"report.md": "a", "scenes/one/report.md": "1"})
    (out / "scenes" / "one" / "report.md").unlink()
    (out / "scenes" / "one").rmdir()
    (out / "scenes" / "one").symlink_to(elsewhere)
    with ReportFolder(out, overwrite=True) as f, pytest.raises(FolderError, match="scenes/one/report.md"):
        stage_files(f, {"report.md": "b", "scenes/one/report.md": "1b"})
    assert list(elsewhere.iterdir()) == [] and (out / "report.md").read_text() == "a"


def test_a_file_that_appears_during_the_run_is_kept_and_so_is_the_new_report(tmp_path):
    with ReportFolder(tmp_path, overwrite=True) as f:
        stage = f.staging()
        (stage / "report.md").write_text("new")
        (tmp_path / "report.md").write_text("the user's, written meanwhile")
        with pytest.raises(FolderError, match="kept in") as err:
            f.commit()
    assert (tmp_path / "report.md").read_text() == "the user's, written meanwhile"
    assert (stage / "report.md").read_text() == "new" and str(stage) in str(err.value)
