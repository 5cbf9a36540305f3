"""The documentation: a short README whose example runs, links that resolve, an API
reference that covers the package and builds without a warning.
"""
from __future__ import annotations

import importlib.util
import os
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
    env.setdefault("MPLBACKEND", "Agg")
    return env


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_readme_is_short_and_has_the_quick_start():
    text = README.read_text()
    assert len(text.splitlines()) <= 200, "README.md is for users: keep it to 200 lines"
    for command in ("make demo", "make test"):
        assert command in text, command
    assert _python_blocks(text), "README.md needs a ```python example"


def test_readme_python_example_runs(tmp_path):
    """The README's first Python block runs as written (in a fresh interpreter,
    in an empty folder) and finds the plate it renders at 4 m."""
    code = _python_blocks(README.read_text())[0]
    script = tmp_path / "readme_example.py"
    script.write_text(code)
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=_env(),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    m = re.search(r"strongest return: ([0-9.]+) m", proc.stdout)
    assert m, proc.stdout
    assert abs(float(m.group(1)) - 4.0) < 0.1, proc.stdout


def test_readme_lists_every_command():
    from sionna_mmir.cli.main import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    table = README.read_text()
    missing = [name for name in sub.choices if f"| `{name}" not in table]
    assert not missing, f"README.md's command table lacks {missing}"


def test_markdown_links_resolve():
    bad = []
    for md in [README, ROOT / "NOTES.md", *sorted(DOCS.glob("*.md"))]:
        for target in re.findall(r"\]\(([^)\s]+)\)", md.read_text()):
            if re.match(r"[a-z]+://", target) or target.startswith("#"):
                continue
            path = target.split("#", 1)[0]
            if not (md.parent / path).exists():
                bad.append(f"{md.relative_to(ROOT)}: {target}")
    assert not bad, "links to missing files:\n" + "\n".join(bad)


def test_api_reference_covers_every_module():
    """``docs/api.rst`` documents every public module (all but the CLI's and
    private ``_name`` modules)."""
    api = (DOCS / "api.rst").read_text()
    listed = set(re.findall(r"^\.\. automodule:: (\S+)", api, flags=re.M))
    missing = []
    for path in sorted((ROOT / "sionna_mmir").rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if "cli" in parts or any(p.startswith("_") for p in parts):
            continue
        name = ".".join(parts)
        if name not in listed:
            missing.append(name)
    assert not missing, f"add to docs/api.rst: {missing}"


def test_sphinx_build_has_no_warnings(tmp_path):
    """``python -m sphinx -W --keep-going -b html docs <tmp>``: every warning
    (an unparseable docstring, a bad reference) fails the build."""
    for module in ("sphinx", "numpydoc", "myst_parser"):
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"{module} is not installed (pip install -e '.[docs]')")
    proc = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-b", "html", "-q",
         str(DOCS), str(tmp_path / "html")],
        cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-5000:] + proc.stderr[-20000:]
    assert (tmp_path / "html" / "api.html").exists()
