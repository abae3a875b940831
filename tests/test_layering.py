"""Command modules sit on top: they import library modules, never the reverse.

A command module parses arguments and prints (``payload/cli.py``, ``*/cli.py``, ``*_cmd.py``,
``payload/demo.py``); what two commands share lives in a library module (``payload.offline``,
``payload.loopback``). Read from the source with ``ast``, imports inside functions included, so
a lazy import cannot hide one.
"""

import ast
import os

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT_DIRS = ("tests", "training", "bench", "sitl", "scripts")


def _module_name(path: str) -> str:
    rel = os.path.relpath(path, REPO)[: -len(".py")].split(os.sep)
    return ".".join(rel[:-1] if rel[-1] == "__init__" else rel)


def _python_files(top: str):
    for folder, dirs, files in os.walk(os.path.join(REPO, top)):
        dirs[:] = sorted(d for d in dirs if not d.startswith((".", "__pycache__")))
        for name in sorted(files):
            if name.endswith(".py"):
                yield os.path.join(folder, name)


PACKAGE = {_module_name(p): p for p in _python_files("payload")}


def is_command(module: str) -> bool:
    last = module.rsplit(".", 1)[-1]
    return module == "payload.demo" or last in ("cli", "__main__") or last.endswith("_cmd")


def imports_of(path: str, module: str):
    """(imported module, name taken from it) for every import in the file; for a whole module
    (``import a.b``, ``from a import b``) one row per attribute the file reads from it, and
    (module, None) when it reads none (or is imported under a dotted name)."""
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    package = module if path.endswith("__init__.py") else module.rpartition(".")[0]
    bound = {}  # local name -> whole module imported under it
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.asname:
                    bound[alias.asname] = alias.name
                else:
                    yield alias.name, None
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            for alias in node.names:
                if "%s.%s" % (base, alias.name) in PACKAGE:  # `from payload.eval import cli`
                    bound[alias.asname or alias.name] = "%s.%s" % (base, alias.name)
                else:
                    yield base, alias.name
    read = {name: set() for name in bound}
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in read:
            read[node.value.id].add(node.attr)
    for name, imported in sorted(bound.items()):
        for attr in sorted(read[name]) or [None]:
            yield imported, attr


def test_the_walk_sees_the_commands_and_the_lazy_imports():
    # the check below means something only if it finds the commands and the imports inside functions
    commands = sorted(m for m in PACKAGE if is_command(m))
    assert commands == ["payload.__main__", "payload.bench.cli", "payload.cli", "payload.demo",
                        "payload.detect_cmd", "payload.eval.cli", "payload.eval.cv_cmd"]
    dispatched = {m for m, _ in imports_of(PACKAGE["payload.cli"], "payload.cli")}
    assert {"payload.detect_cmd", "payload.eval.cli", "payload.demo", "payload.bench.cli"} <= dispatched


@pytest.mark.parametrize("module", sorted(m for m in PACKAGE if not is_command(m)))
def test_library_module_imports_no_command_module(module):
    bad = sorted({m for m, _ in imports_of(PACKAGE[module], module) if m in PACKAGE and is_command(m)})
    assert not bad, "%s (a library module) imports the command module(s) %s" % (module, ", ".join(bad))


def test_scripts_and_tests_take_only_entry_points_and_formats_from_commands():
    # tests, training and bench scripts run a command (`main`) or check what it prints (`format_*`);
    # a helper they need belongs in a library module
    bad = []
    for top in SCRIPT_DIRS:
        for path in _python_files(top):
            for module, name in imports_of(path, _module_name(path)):
                if module in PACKAGE and is_command(module):
                    if name is None or not (name == "main" or name.startswith(("main_", "format_"))):
                        bad.append("%s: %s%s" % (os.path.relpath(path, REPO), module, "" if name is None else "." + name))
    assert not bad, "\n".join(bad)


#: What the detectors (payload.detect) may use of the rest of the package: the layers below them.
BELOW_DETECT = ("payload.boxes", "payload.config", "payload.errors", "payload.types")


def _below_detect(module: str) -> bool:
    return module.startswith("payload.detect.") or any(module == m or module.startswith(m + ".") for m in BELOW_DETECT)


def test_the_layering_walk_sees_the_detectors_factory():
    imported = {m for m, _ in imports_of(PACKAGE["payload.detect.pipeline"], "payload.detect.pipeline")}
    assert "payload.detect.factory" in imported and "payload.detect.ego_motion" in imported


@pytest.mark.parametrize("module", sorted(m for m in PACKAGE if m.startswith("payload.detect.")))
def test_detectors_import_nothing_above_them(module):
    # the shipped models, the service, the CLI, MAVLink sit above the detectors: the factory that
    # builds GLAD from the config is payload.detect.factory, not payload.models
    bad = sorted({m for m, _ in imports_of(PACKAGE[module], module)
                  if (m == "payload" or m.startswith("payload.")) and not _below_detect(m)})
    assert not bad, "%s imports %s, above the detectors" % (module, ", ".join(bad))
