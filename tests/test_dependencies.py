"""Every runtime import of navsvc and roadgraph is installed by the project's runtime
dependencies (pyproject's [project] dependencies and what they require), not only by an
extra: `navsvc send` once crashed with ModuleNotFoundError: httpx in any install without the
test extras, the Docker image included. Checked on the source, offline."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from importlib.metadata import PackageNotFoundError, packages_distributions, requires
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OWN = {"navsvc", "roadgraph"}


def _name(requirement: str) -> str:
    match = re.match(r"[A-Za-z0-9_.-]+", requirement)
    assert match, requirement
    return re.sub(r"[-_.]+", "-", match.group(0)).lower()


OPTIONAL_EXTRAS = ("distributed",)  # imported only inside a guard that names the extra


def _extra_requirements(requirement: str) -> list[str]:
    """What ``name[extra]`` adds to ``name``: its requirements marked for that extra."""
    match = re.match(r"([A-Za-z0-9_.-]+)\[([^\]]+)\]", requirement)
    if not match:
        return []
    wanted = {e.strip() for e in match.group(2).split(",")}
    return [_name(r) for r in requires(match.group(1)) or []
            if any(f'extra == "{e}"' in r for e in wanted)]


def runtime_distributions() -> set[str]:
    """The declared runtime dependencies, those of the optional extras a command asks for
    by name (``OPTIONAL_EXTRAS``), and transitively what they require (extras aside)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    todo = [_name(r) for r in project["dependencies"]]
    for extra in OPTIONAL_EXTRAS:
        for requirement in project["optional-dependencies"][extra]:
            todo += [_name(requirement), *_extra_requirements(requirement)]
    seen: set[str] = set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        try:
            needs = requires(name) or []
        except PackageNotFoundError:
            continue
        todo += [_name(r) for r in needs if "extra" not in r.partition(";")[2]]
    return seen


def runtime_imports() -> dict[str, str]:
    """Top-level third-party modules imported by the packages' source → a file importing it."""
    found: dict[str, str] = {}
    for package in OWN:
        for path in (ROOT / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                    [node.module] if isinstance(node, ast.ImportFrom) and node.module and \
                    node.level == 0 else []
                for name in names:
                    top = name.split(".")[0]
                    if top not in sys.stdlib_module_names and top not in OWN:
                        found.setdefault(top, str(path.relative_to(ROOT)))
    return found


def test_every_runtime_import_comes_with_the_runtime_dependencies() -> None:
    installed = runtime_distributions()
    providers = packages_distributions()
    missing = {}
    for module, where in runtime_imports().items():
        dists = {_name(d) for d in providers.get(module, [module])}
        if not dists & installed:
            missing[module] = where
    assert not missing, f"imported but not a runtime dependency: {missing}"


def test_the_check_sees_the_imports_it_should() -> None:
    imports = runtime_imports()
    assert {"numpy", "fastapi", "websockets", "fastapi_offline"} <= set(imports)
    assert "httpx" not in imports  # the test extra's client stays out of the package


def extras_only_modules() -> set[str]:
    """Top-level modules that only the test and bench extras bring (nothing the runtime
    dependencies or the ``distributed`` extra need)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    runtime = runtime_distributions()
    extras = {_name(r) for extra in ("test", "bench")
              for r in project["optional-dependencies"][extra]}
    only = extras - runtime
    return {module for module, dists in packages_distributions().items()
            if {_name(d) for d in dists} <= only and not module.startswith("_")}


def test_every_command_runs_without_the_test_and_bench_extras(sample_db: Path,
                                                              tmp_path: Path) -> None:
    """Each command's --help, and a short simulate and run, in a Python where every module of
    the test and bench extras fails to import (an install without extras, as in the image;
    `navsvc send` is tested so in tests/api/test_send.py)."""
    import subprocess

    from navsvc import cli

    blocked = sorted(extras_only_modules())
    assert "httpx" in blocked and "pytest" in blocked
    drive, out = str(tmp_path / "d.jsonl"), str(tmp_path / "o.jsonl")
    argvs = [["--help"]] + [[name, "--help"] for name in cli._COMMANDS] + [
        ["simulate", "--map", str(sample_db), "-o", drive, "--duration", "20"],
        ["run", "--map", str(sample_db), "-i", drive, "-o", out, "--quiet"],
        ["evaluate", "--truth", drive, "--estimate", out]]
    code = "\n".join([
        "import sys", f"for m in {blocked!r}:", "    sys.modules[m] = None",
        "from navsvc.cli import main", "import contextlib, io",
        f"for argv in {argvs!r}:",
        "    try:", "        with contextlib.redirect_stdout(io.StringIO()):",
        "            assert main(argv) == 0, argv", "    except SystemExit as exc:",
        "        assert exc.code in (0, None), (argv, exc.code)",
        "print('ok')"])
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0 and done.stdout.strip().endswith("ok"), done.stderr
    assert Path(out).read_text().count("\n") >= 15  # the run wrote its positions
