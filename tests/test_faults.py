"""Faults a long run meets: Ctrl-C and SIGTERM at any moment, a run killed outright, a folder the system
refuses, a disk that fills. Each must end with one line that says what happened and what was kept, and a
manifest that says the same; none may be lost or pass for success.

The signals are real (``os.kill`` of this process) and arrive while a stand-in command compiles a JAX
program, reports progress, writes a file, runs a garbage-collection callback (where Python discards a
KeyboardInterrupt) or has passed its last safe point.
"""

import errno
import gc
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from biped_jax import cli
from biped_jax.report import interrupts, outputs
from biped_jax.report.progress import live_progress

MOMENTS = ("compiling", "solving", "writing", "gc callback", "after the last safe point")


def _stand_in(moment: str, number: int):
    """A command that finishes a stage and a file, then meets ``moment`` with signal ``number`` sent,
    then would write a second result."""
    import jax
    import jax.numpy as jnp

    def run(args):
        out = args.out
        outputs.stage(out, "first", {"k": 1}, lambda: {"x": 1}, resume=args.resume)
        outputs.write_json(out / "first.json", {"done": True})
        send = lambda: os.kill(os.getpid(), number)  # noqa: E731
        if moment == "compiling":
            from biped_jax.report.progress import listeners
            listeners.append(lambda name: send() if name else None)  # during the compile log
            try:
                jax.jit(lambda x: jnp.sin(x) * 3.0 + moment.__len__())(jnp.ones(7)).block_until_ready()
            finally:
                listeners.pop()
        elif moment == "solving":
            with live_progress() as progress:
                send()
                for i in range(3):
                    progress(f"iteration {i}")
        elif moment == "writing":
            send()
        elif moment == "gc callback":
            def callback(phase, info):
                if phase == "start":
                    send()
                    sum(range(1000))  # Python runs the handler here, inside the callback
            gc.callbacks.append(callback)
            try:
                gc.collect()
            finally:
                gc.callbacks.remove(callback)
        outputs.write_json(out / "second.json", {"done": True})
        if moment == "after the last safe point":
            send()
        return 0
    return run


@pytest.mark.parametrize("number", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("moment", MOMENTS)
def test_a_signal_at_any_moment_stops_the_run_and_says_so(capsys, tmp_path, monkeypatch, moment, number):
    monkeypatch.setitem(cli.RUNS, "reproduce", _stand_in(moment, number))
    status = cli.main(["reproduce", "--out", str(tmp_path)])
    assert status == {signal.SIGINT: 130, signal.SIGTERM: 143}[number]
    error = capsys.readouterr().err
    assert "Traceback" not in error and "Exception ignored" not in error
    last = error.strip().splitlines()[-1]
    assert last.startswith("interrupted:" if number == signal.SIGINT else "terminated:"), error
    manifest = outputs.read_manifest(tmp_path)
    assert manifest["state"] == "interrupted" and manifest["message"] == interrupts.REASON[number]
    assert "stages/first.pkl" in manifest["files"] and "first.json" in manifest["files"]
    wrote_second = moment == "after the last safe point"
    assert ("second.json" in manifest["files"]) == wrote_second == (tmp_path / "second.json").exists()
    # the handlers are the caller's again
    assert signal.getsignal(signal.SIGINT) is not interrupts._handler


def test_resume_after_an_interruption_takes_the_finished_stages(capsys, tmp_path, monkeypatch):
    monkeypatch.setitem(cli.RUNS, "reproduce", _stand_in("writing", signal.SIGINT))
    assert cli.main(["reproduce", "--out", str(tmp_path)]) == 130
    assert "--resume continues from the finished stages" in capsys.readouterr().err

    def resumed(args):
        computed = []
        value = outputs.stage(args.out, "first", {"k": 1}, lambda: computed.append(1) or {"x": 2}, resume=True)
        assert value == {"x": 1} and not computed  # the stage of the interrupted run
        outputs.write_json(args.out / "second.json", {"done": True})
        return 0
    monkeypatch.setitem(cli.RUNS, "reproduce", resumed)
    assert cli.main(["reproduce", "--out", str(tmp_path), "--resume"]) == 0
    manifest = outputs.read_manifest(tmp_path)
    assert manifest["state"] == "completed" and manifest["resumed_from"]["state"] == "interrupted"


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def _running_manifest(folder: Path, pid: int) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    record = {"command": ["biped-jax", "reproduce"], "state": "running", "started": "2026-12-03T10:00:00+00:00",
              "ended": None, "files": ["results.json"], "message": None,
              "process": {"pid": pid, "host": os.uname().nodename}}
    (folder / outputs.MANIFEST).write_text(json.dumps(record))
    (folder / "results.json").write_text('{"partial": true}')


def test_a_run_that_was_killed_is_reported_and_set_aside(capsys, tmp_path, monkeypatch):
    _running_manifest(tmp_path, _dead_pid())
    monkeypatch.setitem(cli.RUNS, "reproduce", lambda args: outputs.write_json(args.out / "results.json", {}) and 0)
    assert cli.main(["reproduce", "--out", str(tmp_path)]) == 0
    error = capsys.readouterr().err.replace("\n", "")  # the console wraps long paths at its width, mid-word
    assert "stopped without finishing" in error and "results.json" in error and "previous" in error
    earlier = json.loads((tmp_path / outputs.PREVIOUS / outputs.MANIFEST).read_text())
    assert earlier["state"] == outputs.DIED
    assert json.loads((tmp_path / outputs.PREVIOUS / "results.json").read_text()) == {"partial": True}
    assert outputs.read_manifest(tmp_path)["state"] == "completed"


def test_a_folder_another_live_run_writes_to_is_refused(capsys, tmp_path, monkeypatch):
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        _running_manifest(tmp_path, sleeper.pid)
        monkeypatch.setitem(cli.RUNS, "reproduce", lambda args: pytest.fail("ran in a folder in use"))
        assert cli.main(["reproduce", "--out", str(tmp_path)]) == 1
        error = capsys.readouterr().err
        assert f"another run (process {sleeper.pid}" in error and "Traceback" not in error
        assert json.loads((tmp_path / "results.json").read_text()) == {"partial": True}  # untouched
    finally:
        sleeper.kill()
        sleeper.wait()


@pytest.mark.parametrize("path", ["/proc/biped-out", "/proc/self/biped-out/deeper", "/dev/null/out"])
def test_a_folder_the_system_refuses_is_named_before_any_work(capsys, path):
    with pytest.raises(SystemExit) as stop:
        cli.main(["reproduce", "--out", path])
    assert stop.value.code == 2
    error = capsys.readouterr().err
    assert f"--out {path}:" in error and "Traceback" not in error


def test_the_folder_check_leaves_nothing_behind(tmp_path):
    assert outputs.check_output_dir(tmp_path / "a" / "b" / "c") == tmp_path / "a" / "b" / "c"
    assert list(tmp_path.iterdir()) == []


def test_a_disk_that_fills_keeps_the_earlier_files_and_says_so(capsys, tmp_path, monkeypatch):
    with outputs.run_manifest(tmp_path, ["earlier"]):
        outputs.write_json(tmp_path / "table.json", {"from": "earlier"})
    real_write = Path.write_text

    def full_after_first(self, text, *args, **kwargs):  # the file system fills after the first result
        if self.parent == tmp_path and self.name.startswith(".") and written:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        if self.name.startswith(".results."):
            written.append(self.name)
        return real_write(self, text, *args, **kwargs)
    written = []

    def run(args):
        outputs.write_json(args.out / "results.json", {"from": "this run"})
        outputs.write_json(args.out / "table.json", {"from": "this run"})
        return 0
    monkeypatch.setattr(Path, "write_text", full_after_first)
    monkeypatch.setitem(cli.RUNS, "reproduce", run)
    assert cli.main(["reproduce", "--out", str(tmp_path)]) == 1
    monkeypatch.undo()
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "No space left on device" in last and "intact" in last and "results.json" in last, last
    assert json.loads((tmp_path / "results.json").read_text()) == {"from": "this run"}
    assert json.loads((tmp_path / "previous" / "table.json").read_text()) == {"from": "earlier"}
    assert not (tmp_path / "table.json").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left
