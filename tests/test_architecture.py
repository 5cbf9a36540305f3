"""The package's structure: layers, no import cycles, short functions, no history.

* every module imports only from its own layer or lower ones (the signal path
  reads bottom-up: radar -> materials -> ADC / processing -> captures ->
  scene -> paths -> effects -> fit / residual -> comparisons -> CLI);
* no two modules import each other, directly or through others (imports
  inside functions count: they are dependencies too);
* no function in the package is longer than 120 lines, and the solver's
  ``__call__`` (the orchestrator) stays under 80;
* no tracked file narrates the project's development (round labels, work
  diaries): docs state intent and results, not when they happened;
* ``comparisons/`` and ``benchmarks/`` use the library, never the CLI.
"""
from __future__ import annotations

import ast
import pathlib
import re
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PKG = ROOT / "sionna_mmir"

#: layer of each top-level module or subpackage (higher may import lower)
LAYERS = {
    "errors": 0, "utils": 0,
    "radar": 1,
    "radio_materials": 2, "radio_devices": 2, "metrics": 2, "bsdf": 2,
    "fmcw": 3, "processing": 3,
    "captures": 4, "plotting": 4,
    "scene": 5, "scaffold": 5,
    "paths": 6,
    "effects": 7, "baseline": 7, "benchmark_scenes": 7, "occupancy": 7,
    "fit": 8, "residual": 8, "dataset": 8, "independent": 8,
    "pipeline": 9, "compare": 9,
    "cli": 10, "__main__": 10,
}


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield ".".join(parts), path


def _imports(name, path):
    """Modules of the package that ``name`` imports (anywhere in the file)."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.startswith("sionna_mmir"):
                for alias in node.names:
                    full = f"{mod}.{alias.name}"
                    out.add(full if _exists(full) else mod)
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("sionna_mmir")}
    return {m for m in out if m != name}


def _exists(mod):
    p = ROOT / pathlib.Path(*mod.split("."))
    return p.with_suffix(".py").exists() or (p / "__init__.py").exists()


def _top(mod):
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 else None


GRAPH = {name: _imports(name, path) for name, path in _modules()}


def test_01_every_package_has_a_layer():
    tops = {_top(m) for m in GRAPH} - {None}
    assert not tops - set(LAYERS), f"give these a layer: {sorted(tops - set(LAYERS))}"


def test_02_no_import_from_a_higher_layer():
    bad = []
    for mod, deps in GRAPH.items():
        a = _top(mod)
        if a is None:
            continue
        for d in deps:
            b = _top(d)
            if b is not None and b in LAYERS and LAYERS[b] > LAYERS[a]:
                bad.append(f"{mod} -> {d}")
    assert not bad, "upward imports:\n" + "\n".join(sorted(bad))


def test_03_no_import_cycles():
    graph = {m: {d for d in deps if d in GRAPH} for m, deps in GRAPH.items()
             if _top(m) is not None}
    index, low, stack, on, cycles = {}, {}, [], set(), []

    def visit(v):                                   # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    # a package __init__ re-exporting its modules is not a cycle of behaviour
    cycles = [c for c in cycles if not all(_is_reexport(m, c) for m in c)]
    assert not cycles, f"import cycles: {cycles}"


def _is_reexport(mod, comp):
    return (PKG / pathlib.Path(*mod.split(".")[1:]) / "__init__.py").exists()


def _functions():
    for name, path in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield name, node


def test_04_functions_are_short():
    long = [f"{m}.{n.name}: {n.end_lineno - n.lineno + 1} lines" for m, n in _functions()
            if n.end_lineno - n.lineno + 1 > 120]
    assert not long, "functions over 120 lines:\n" + "\n".join(long)


def test_05_the_solver_call_only_orchestrates():
    calls = [n for m, n in _functions() if m == "sionna_mmir.paths.solver"
             and n.name == "__call__"]
    assert len(calls) == 1
    assert calls[0].end_lineno - calls[0].lineno + 1 < 80


def _tracked():
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [ROOT / f for f in out if (ROOT / f).is_file()]


#: words that narrate when work was done (``[e]`` keeps this file from matching itself)
HISTORY = re.compile(r"\bs[e]ssions?\b|\bround [0-9]+ of (the )?work|"
                     r"\bs[e]ssion[ _-]?[0-9]+", re.IGNORECASE)


def test_06_no_development_history_in_tracked_files():
    hits = []
    for f in _tracked():
        if f.suffix not in (".py", ".md", ".txt", ".toml", ".cfg", ".sh", ".csv", ".json",
                            ".rst", ""):
            continue
        if HISTORY.search(f.name):
            hits.append(f"{f.relative_to(ROOT)} (file name)")
        try:
            text = f.read_text()
        except UnicodeDecodeError:
            continue
        for i, line in enumerate(text.splitlines(), 1):
            if HISTORY.search(line):
                hits.append(f"{f.relative_to(ROOT)}:{i}: {line.strip()[:80]}")
    assert not hits, "development history in tracked files:\n" + "\n".join(hits[:40])


def test_07_comparisons_and_benchmarks_use_the_library_not_the_cli():
    bad = []
    for folder in ("comparisons", "benchmarks"):
        for f in (ROOT / folder).rglob("*.py"):
            if re.search(r"sionna_mmir\.cli\b|from sionna_mmir import cli", f.read_text()):
                bad.append(str(f.relative_to(ROOT)))
    assert not bad, bad
