"""The documentation: the API reference builds from the docstrings without a warning, and every module
path and document the code names exists in the repository."""

import importlib
import importlib.util
import re
import warnings
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent


#: Markdown files the commands write (results, not documents), and a test's file name.
RESULT_FILES = {"tables.md", "drives.md", "heuristic_step.md", "t.md"}


def _sources():
    return sorted(p for folder in ("biped_jax", "benchmarks", "tests") for p in (ROOT / folder).rglob("*.py"))


def test_the_api_reference_builds_without_warnings(tmp_path):
    """``python docs/build_api.py`` (pdoc, in the test and docs extras) into a temporary folder."""
    spec = importlib.util.spec_from_file_location("build_api", ROOT / "docs" / "build_api.py")
    build_api = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build_api)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        build_api.build(tmp_path)
    messages = [str(w.message) for w in caught if "biped_jax" in str(w.message) or w.category is UserWarning]
    assert messages == []
    pages = {p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*.html")}
    assert {"biped_jax.html", "biped_jax/gait/solver.html", "biped_jax/optim/interior_point.html"} <= pages


def _resolves(path: str) -> bool:
    """Whether ``biped_jax.a.b.c`` is a module, or an attribute of the longest module prefix."""
    parts = path.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            target = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for name in parts[cut:]:
            if not hasattr(target, name):
                return False
            target = getattr(target, name)
        return True
    return False


def test_every_module_path_the_code_names_exists():
    named = {}
    for source in _sources():
        for match in re.finditer(r"\bbiped_jax(?:\.[A-Za-z_][A-Za-z0-9_]*)+", source.read_text()):
            if not match.group(0).endswith((".html", ".a.b.c")):  # this file's own examples
                named.setdefault(match.group(0), source.relative_to(ROOT).as_posix())
    missing = {path: where for path, where in named.items() if not _resolves(path)}
    assert not missing, missing


def test_every_document_the_code_and_the_docs_name_is_in_the_repository():
    texts = {p.relative_to(ROOT).as_posix(): p.read_text() for p in _sources()}
    texts.update({p.relative_to(ROOT).as_posix(): p.read_text()
                  for p in [ROOT / "README.md", ROOT / "CHANGELOG.md", *(ROOT / "docs").glob("*.md")]})
    missing = {}
    for where, text in texts.items():
        for match in re.finditer(r"[\w./-]*[\w-]\.md\b", text):
            name = match.group(0)
            if name.split("/")[-1] in RESULT_FILES:
                continue
            folder = (ROOT / where).parent
            if not any((base / name).is_file() for base in (ROOT, ROOT / "docs", ROOT / "benchmarks", folder)):
                missing.setdefault(name, where)
    assert not missing, missing
