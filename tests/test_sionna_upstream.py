"""Tests of patches/: upstreamable patches against the installed sionna-rt 2.2.0.

The installed package is never modified: the patches are applied to copies in
a temporary folder, and each reproduction (``patches/repro/NNNN_*.py``) runs
in a subprocess twice, against the installed package (``--expect bug``) and
against the patched copy put in front through ``PYTHONPATH``
(``--expect fixed``).  The scripts import ``sionna_mmir`` first, which sets
``DRJIT_LIBLLVM_PATH`` before Dr.Jit starts.  ``patches/check.sh`` runs the
same checks, the expensive ones included.
"""
from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import pathlib
import re
import shutil
import subprocess
import sys

import pytest

REPO_ROOT = pathlib.Path(__file__).resolve().parents[1]
PATCH_DIR = REPO_ROOT / "patches"
REPRO_DIR = PATCH_DIR / "repro"
PATCHES = sorted(PATCH_DIR.glob("[0-9][0-9][0-9][0-9]-*.patch"))
REPROS = sorted(REPRO_DIR.glob("[0-9][0-9][0-9][0-9]_*.py"))
SIONNA_VERSION = "2.2.0"
#: Reproductions left to ``patches/check.sh``, with the reason.
EXPENSIVE = {"0005": "no patch (documents a limitation) and runs a crashing child "
                     "process; run `patches/check.sh 0005`"}
#: Problems ``patch`` reports that make an application unclean.
UNCLEAN = re.compile(r"fuzz|offset|fail|reversed|malformed|garbage", re.IGNORECASE)

needs_patch = pytest.mark.skipif(
    shutil.which("patch") is None,
    reason="the 'patch' executable is missing (apt-get install patch): "
           "the patches in patches/ cannot be applied")


def _installed_sionna() -> pathlib.Path:
    """Folder of the installed ``sionna`` package; skips unless it is sionna-rt 2.2.0."""
    try:
        version = importlib.metadata.version("sionna-rt")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("sionna-rt is not installed")
    if version != SIONNA_VERSION:
        pytest.skip(f"the patches target sionna-rt {SIONNA_VERSION}, installed is {version}")
    spec = importlib.util.find_spec("sionna")
    return pathlib.Path(list(spec.submodule_search_locations)[0])


def _touched_files(patch: pathlib.Path) -> list[str]:
    """Paths (relative to the package's parent) a patch modifies."""
    return [line[len("+++ b/"):].split("\t")[0].strip()
            for line in patch.read_text().splitlines() if line.startswith("+++ b/")]


def _patch(cwd: pathlib.Path, patch: pathlib.Path, dry_run: bool) -> subprocess.CompletedProcess:
    cmd = ["patch", "-p1", "--batch", "--no-backup-if-mismatch"] + (["--dry-run"] if dry_run else [])
    with open(patch, "rb") as f:
        return subprocess.run(cmd, cwd=cwd, stdin=f, capture_output=True, text=True, timeout=60)


@pytest.fixture(scope="module")
def pristine_files(tmp_path_factory) -> pathlib.Path:
    """Copies of just the installed files the patches touch (enough for dry runs)."""
    src = _installed_sionna().parent
    dst = tmp_path_factory.mktemp("sionna-pristine")
    for patch in PATCHES:
        for rel in _touched_files(patch):
            (dst / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src / rel, dst / rel)
    return dst


@pytest.fixture(scope="module")
def patched_copy(tmp_path_factory) -> pathlib.Path:
    """A full copy of the installed package with all patches applied in order."""
    src = _installed_sionna()
    root = tmp_path_factory.mktemp("sionna-patched")
    shutil.copytree(src, root / "sionna", ignore=shutil.ignore_patterns("__pycache__"))
    for patch in PATCHES:
        for dry_run in (True, False):
            res = _patch(root, patch, dry_run)
            if res.returncode != 0 or UNCLEAN.search(res.stdout + res.stderr):
                pytest.fail(f"{patch.name} does not apply cleanly in series "
                            f"(dry_run={dry_run}):\n{res.stdout}{res.stderr}")
    return root


def _env(pythonpath: pathlib.Path | None) -> dict:
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    return env


def _start(script: pathlib.Path, expect: str, pythonpath: pathlib.Path | None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(script), "--expect", expect], cwd=REPO_ROOT,
                            env=_env(pythonpath), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def _finish(proc: subprocess.Popen, label: str) -> str:
    try:
        out, _ = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        pytest.fail(f"{label}: timed out\n{out[-3000:]}")
    lines = [ln for ln in out.splitlines() if ln.startswith(("PASS ", "FAIL "))]
    assert proc.returncode == 0 and lines and lines[-1].startswith("PASS "), \
        f"{label}: exit status {proc.returncode}\n{out[-3000:]}"
    return lines[-1]


def test_01_patches_exist_and_target_the_sionna_package():
    assert PATCHES, "no patches in patches/"
    for patch in PATCHES:
        files = _touched_files(patch)
        assert files, f"{patch.name}: not a unified diff with a/ b/ paths"
        assert all(f.startswith("sionna/") for f in files), (patch.name, files)


@needs_patch
@pytest.mark.parametrize("patch", PATCHES, ids=lambda p: p.name[:4])
def test_02_each_patch_applies_cleanly_on_its_own(pristine_files, patch):
    """Dry run of each patch on copies of the installed 2.2.0 files: no fuzz, no offset."""
    res = _patch(pristine_files, patch, dry_run=True)
    assert res.returncode == 0, res.stdout + res.stderr
    assert not UNCLEAN.search(res.stdout + res.stderr), res.stdout + res.stderr


@needs_patch
def test_03_all_patches_apply_in_series(patched_copy):
    """Dry run then real application, in order, on a full copy of the package."""
    pkg = patched_copy / "sionna" / "rt"
    text = (pkg / "path_solvers" / "image_method.py").read_text()
    assert "return_vertices=True" in text.split("def _compute_images")[1].split("def ")[0]
    assert "scene_cls" in (pkg / "scene.py").read_text()
    # the installed package is untouched
    installed = _installed_sionna() / "rt" / "scene.py"
    assert "scene_cls" not in installed.read_text()


def test_04_readme_documents_every_patch_and_reproduction():
    readme = (PATCH_DIR / "README.md").read_text()
    for patch in PATCHES:
        assert patch.name in readme, f"patches/README.md does not mention {patch.name}"
        assert "Upstream status: not submitted" in patch.read_text(), patch.name
    for repro in REPROS:
        assert repro.name in readme, f"patches/README.md does not mention {repro.name}"
    numbers = {p.name[:4] for p in PATCHES}
    assert numbers <= {r.name[:4] for r in REPROS}, "every patch needs a reproduction"
    assert os.access(PATCH_DIR / "check.sh", os.X_OK), "patches/check.sh must be executable"


@needs_patch
@pytest.mark.parametrize("repro", REPROS, ids=lambda p: p.name[:4])
def test_05_reproduction_shows_bug_installed_and_fix_patched(patched_copy, repro):
    """The script passes with --expect bug on the installed package and --expect
    fixed on the patched copy (both subprocesses run concurrently)."""
    number = repro.name[:4]
    if number in EXPENSIVE:
        pytest.skip(EXPENSIVE[number])
    has_patch = any(p.name.startswith(number + "-") for p in PATCHES)
    procs = [(f"{repro.name} (installed, --expect bug)", _start(repro, "bug", None)),
             (f"{repro.name} (patched, --expect {'fixed' if has_patch else 'bug'})",
              _start(repro, "fixed" if has_patch else "bug", patched_copy))]
    lines = [_finish(p, label) for label, p in procs]
    assert "observed bug" in lines[0] and str(patched_copy) in lines[1], lines
