"""Result files: strict JSON, atomic writes, an output folder checked before any work, and a manifest
that says which files a run wrote and whether it finished.

Every study writes through these functions, so that

- no JSON file contains ``NaN`` or ``Infinity`` (not JSON; other tools refuse it): a non-finite number
  is written as ``null`` and the record around it says why (a status);
- a file is either the old one or the complete new one, never half written (temporary file in the
  same folder, then :func:`os.replace`);
- ``manifest.json`` names the command, the package versions, the start and end times, the state
  (``running``, ``completed``, ``interrupted``, ``failed``) and every file this run wrote; the files
  of the run before are moved to ``previous/`` when a new one starts, so a stale file can never pass
  for a new one.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import math
import os
import platform
import sys
import tempfile
from importlib import metadata
from pathlib import Path
from typing import Any, Callable

from biped_jax.report import interrupts

MANIFEST = "manifest.json"
#: Subfolder that receives an earlier run's files when a new run starts in the same folder.
PREVIOUS = "previous"

_stamps: list[str] = []  # the innermost :func:`stamped` block's text is written into every result file


@contextlib.contextmanager
def stamped(text: str):
    """Every result file written in the block says ``text`` (e.g. that it is a quick, coarse look and
    not the study): JSON objects get a first key "stamp", markdown starts with it in bold, figures
    carry it in red across the top, ``.npz`` files get an array "stamp", and the run's manifest records
    it."""
    _stamps.append(text)
    if _current is not None:
        _current.record["stamp"] = text
        _current.write()
    try:
        yield
    finally:
        _stamps.pop()


def check_output_dir(path: Path) -> Path:
    """Refuses, before any computing, an output folder that cannot be written: an existing file, a
    path below a file, a folder (or its nearest existing parent) without write permission, or one the
    system refuses to make or write in (tried, then removed: nothing is left behind). Raises ValueError
    naming the path and the reason; returns the path."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"--out {path}: is a file, not a folder")
    existing = path
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"--out {path}: {existing} is a file, so no folder can be made below it")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"--out {path}: {existing} is not writable")
    _probe(path, existing)
    return path


def _probe(path: Path, existing: Path) -> None:
    """Makes the missing folders of ``path`` and a file in it, then removes them again: what the
    permission bits do not tell (a path the OS refuses, a read-only or full file system, /proc)."""
    made = []
    try:
        missing, folder = [], path
        while folder != existing:  # existing is path or one of its parents
            missing.append(folder)
            folder = folder.parent
        for folder in reversed(missing):
            folder.mkdir()
            made.append(folder)
        handle, probe = tempfile.mkstemp(prefix=".probe.", dir=path)
        os.close(handle)
        os.remove(probe)
    except OSError as error:
        raise ValueError(f"--out {path}: cannot be written ({error.strerror or error})") from None
    finally:
        for folder in reversed(made):
            with contextlib.suppress(OSError):
                folder.rmdir()


def finite_or_none(value: Any) -> Any:
    """``value`` with every non-finite float (Python or numpy, at any depth of dicts, lists, tuples and
    arrays) replaced by None, and numpy scalars and arrays by Python numbers and lists."""
    if isinstance(value, dict):
        return {str(k): finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):  # numpy arrays and scalars
        return finite_or_none(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def json_text(record: Any) -> str:
    """Strict JSON (``allow_nan=False``) of ``record`` after :func:`finite_or_none`."""
    return json.dumps(finite_or_none(record), indent=2, allow_nan=False) + "\n"


def _umask() -> int:
    """The process's file-creation mask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def _atomic(path: Path, suffix: str, listed: bool = True):
    """Yields a temporary path in ``path``'s folder; moves it onto ``path`` only if the block ends
    without an exception (else removes it); ``listed`` adds it to the running manifest."""
    if listed:  # a result file is a safe point to stop at (the manifest's own writes are not)
        interrupts.checkpoint()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix, dir=path.parent)
    os.close(handle)
    try:
        yield Path(temporary)
        # mkstemp's file is private (0600); a result is as readable as the user's umask says
        os.chmod(temporary, 0o666 & ~_umask())
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)
    if listed:
        _record(path)


def write_text(path: Path, text: str) -> Path:
    """Writes ``text`` to ``path`` atomically (markdown with the :func:`stamped` text first)."""
    if _stamps and Path(path).suffix == ".md":
        text = f"**{_stamps[-1]}**\n\n{text}"
    with _atomic(path, ".tmp") as temporary:
        temporary.write_text(text)
    return Path(path)


def write_bytes(path: Path, data: bytes) -> Path:
    """Writes ``data`` to ``path`` atomically."""
    with _atomic(path, ".tmp") as temporary:
        temporary.write_bytes(data)
    return Path(path)


def write_json(path: Path, record: Any) -> Path:
    """Writes ``record`` as strict JSON (see :func:`json_text`) atomically (an object with the
    :func:`stamped` text as its first key "stamp")."""
    if _stamps and isinstance(record, dict):
        record = {"stamp": _stamps[-1], **record}
    return write_text(path, json_text(record))


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend (every figure of the package is written to a file)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_figure(figure, path: Path, dpi: int = 110) -> Path:
    """Saves a matplotlib figure atomically (the format from ``path``'s suffix)."""
    path = Path(path)
    extra = {}
    if _stamps:  # above everything (the figure grows to hold it), so that no title hides it
        figure.text(0.5, 1.0, _stamps[-1], color="red", ha="center", va="bottom", fontsize=10)
        extra = {"bbox_inches": "tight"}
    with _atomic(path, path.suffix) as temporary:
        figure.savefig(temporary, dpi=dpi, format=path.suffix.lstrip("."), **extra)
    return path


def save_npz(path: Path, compressed: bool = False, **arrays) -> Path:
    """Saves numpy arrays to an ``.npz`` file atomically."""
    import numpy as np
    if _stamps:
        arrays = {"stamp": np.array(_stamps[-1]), **arrays}
    with _atomic(Path(path), ".npz") as temporary:
        (np.savez_compressed if compressed else np.savez)(temporary, **arrays)
    return Path(path)


def read_npz(path: Path) -> dict:
    """Every array of an ``.npz`` file (no pickled objects); ValueError saying why the file cannot be
    read (the caller names the file and what it was for)."""
    import zipfile

    import numpy as np
    if not zipfile.is_zipfile(path):  # np.load would call a text file "pickled data"
        raise ValueError("not a readable .npz file (not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {key: data[key] for key in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise ValueError(f"not a readable .npz file ({error})") from None


#: Where a study keeps its finished stages (for ``--resume``), inside the output folder.
STAGES = "stages"


def stage(out: Path, name: str, key: dict, compute: Callable[[], object], resume: bool,
          say: Callable[[str], None] = lambda message: None):
    """The result of one stage of a long study: loaded from ``out/stages/name.pkl`` when ``resume`` is
    set and that file was written by a run with the same ``key`` (the settings that decide the
    result), else computed and saved there (atomically) before it is returned.

    The files are Python pickles written by this package for this folder: load only your own."""
    import pickle
    interrupts.checkpoint()  # between stages
    path = Path(out) / STAGES / f"{name}.pkl"
    if resume and path.is_file():
        try:
            saved = pickle.loads(path.read_bytes())
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError) as error:
            say(f"{path}: unreadable ({type(error).__name__}), computing the stage again")
        else:
            if saved.get("key") == key:
                say(f"resumed: {name} from {path}")
                return saved["value"]
            say(f"{path} was written with other settings, computing the stage again")
    value = compute()
    write_bytes(path, pickle.dumps({"key": key, "value": value}))
    return value


def _versions() -> dict:
    names = ("biped_jax", "jax", "jaxlib", "mujoco", "mujoco-mjx", "optax", "numpy")
    found = {}
    for name in names:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = None
    return found | {"python": platform.python_version()}


class _Run:
    """The manifest of the run under way (at most one per process)."""

    def __init__(self, folder: Path, command: list[str]):
        self.folder = Path(folder)
        self.record = {"command": command, "state": "running", "versions": _versions(),
                       "started": _now(), "ended": None, "files": [], "message": None,
                       "process": {"pid": os.getpid(), "host": platform.node()}}

    def write(self):
        path = self.folder / MANIFEST
        with _atomic(path, ".tmp", listed=False) as temporary:
            temporary.write_text(json_text(self.record))


_current: _Run | None = None


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _record(path: Path):
    if _current is None:
        return
    try:
        relative = str(Path(path).resolve().relative_to(_current.folder.resolve()))
    except ValueError:
        return
    if relative != MANIFEST and relative not in _current.record["files"]:
        _current.record["files"].append(relative)
        _current.write()


def read_manifest(folder: Path) -> dict | None:
    """The manifest in ``folder``, or None when there is none (or it is unreadable)."""
    try:
        return json.loads((Path(folder) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None


def _set_aside_previous(folder: Path) -> None:
    """Moves the files an earlier run's manifest lists into ``folder/previous/`` (replacing what an
    even earlier run left there), so that none of them passes for a result of the run now starting."""
    earlier = read_manifest(folder)
    if not earlier:
        return
    aside = folder / PREVIOUS
    for name in earlier.get("files", []):
        source = folder / name
        if source.is_file() and aside not in source.parents:
            target = aside / name
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(source, target)
    aside.mkdir(exist_ok=True)  # the earlier manifest is kept with them: what that run was and how it ended
    os.replace(folder / MANIFEST, aside / MANIFEST)


class FolderInUse(ValueError):
    """Another live process is running a command in the output folder."""


#: The state an earlier run's manifest is given when it said ``running`` and its process is gone.
DIED = "died"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, under another user
        return True
    return True


def _check_earlier(folder: Path, earlier: dict | None, say: Callable[[str], None], resume: bool) -> dict | None:
    """An earlier manifest still saying ``running``: refused (FolderInUse) when its process lives on
    this host, else reported and marked :data:`DIED` (the process was killed, or the machine stopped)."""
    if not earlier or earlier.get("state") != "running":
        return earlier
    process = earlier.get("process") or {}
    pid, host = process.get("pid"), process.get("host")
    if isinstance(pid, int) and host == platform.node() and pid != os.getpid() and _alive(pid):
        raise FolderInUse(f"--out {folder}: another run (process {pid}, started {earlier.get('started')}: "
                          f"{' '.join(earlier.get('command') or [])}) is writing here; wait for it to end "
                          "or give another --out")
    files = earlier.get("files") or []
    say(f"an earlier run in {folder} (started {earlier.get('started')}) stopped without finishing (its process "
        f"is gone: killed, or the machine stopped); it had written {', '.join(files) or 'nothing'}"
        + ("; this run continues from its finished stages" if resume else f"; set aside in {folder / PREVIOUS}"))
    earlier = {**earlier, "state": DIED, "message": "the process ended without closing its manifest"}
    with _atomic(folder / MANIFEST, ".tmp", listed=False) as temporary:
        temporary.write_text(json_text(earlier))
    return earlier


@contextlib.contextmanager
def run_manifest(folder: Path, command: list[str] | None = None, resume: bool = False,
                 say: Callable[[str], None] = lambda message: None):
    """Keeps ``folder/manifest.json`` for the block: state ``running`` with no files at the start,
    each file written through this module listed as it lands, and at the end ``completed``,
    ``interrupted`` (Ctrl-C) or ``failed`` (with the error), and the end time. The files an earlier
    run's manifest listed are moved to ``folder/previous/`` first, unless ``resume`` (the run continues
    from them; the manifest notes the run it resumed). An earlier manifest that still says
    ``running`` is reported through ``say`` and marked :data:`DIED` when its process is gone, and
    refused (:class:`FolderInUse`) when it still runs. The exception, if any, propagates."""
    global _current, _last
    _last = None
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    earlier = _check_earlier(folder, read_manifest(folder), say, resume)
    if not resume:
        _set_aside_previous(folder)
    run = _Run(folder, list(sys.argv) if command is None else command)
    if earlier and resume:
        run.record["resumed_from"] = {k: earlier.get(k) for k in ("started", "state", "files")}
    previous, _current = _current, run
    _last = run.record
    failing = False
    try:
        run.write()
        yield run
    except KeyboardInterrupt as error:
        failing = True
        run.record.update(state="interrupted", message=str(error) if isinstance(error, interrupts.Interrupted)
                          else interrupts.REASON[interrupts.signal.SIGINT])
        raise
    except BaseException as error:
        failing = True
        run.record.update(state="failed", message=f"{type(error).__name__}: {error}")
        raise
    else:
        run.record["state"] = "completed"
    finally:
        run.record["ended"] = _now()
        _current = previous
        try:
            run.write()
        except OSError:
            if not failing:
                raise  # else the error under way says more (e.g. the disk is full: so is the manifest's)


_last: dict | None = None  # the record of the latest run_manifest block


def last_run() -> dict | None:
    """The manifest record of the latest :func:`run_manifest` block in this process (as it is in memory,
    also when the file could not be written), or None."""
    return _last
