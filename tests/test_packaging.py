"""Packaging: the wheel carries the default lenses and configs, and an installed wheel works
outside the checkout (``deeplens report``, ``deeplens design sensitivity``, a tiny training).

The fast tests build the wheel (a few seconds) and read it; the slow one installs it into a
fresh virtual environment and runs the commands from a folder outside the checkout.  That
environment gets the wheel alone (``pip install --no-deps``); torch, Lightning and the other
dependencies come from this interpreter's site-packages through a ``.pth`` line appended
*after* the new environment's own site-packages, so reinstalling torch is not needed and the
installed ``deeplens`` (not this checkout's) is the one imported, which the test checks.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: what a build needs from the checkout (setup.py copies data/lenses and configs as package data)
SOURCES = ["pyproject.toml", "setup.py", "MANIFEST.in", "README.md", "LICENSE", "deeplens",
           "configs", "data/lenses"]


#: what the test wheels record as the commit they were built from
BUILD_COMMIT = "abc1234"


def build_wheel(dest: Path) -> Path:
    """Build the wheel from a copy of the checkout's sources (the checkout stays clean)."""
    src = dest / "src"
    for name in SOURCES:
        s, d = REPO / name, src / name
        d.parent.mkdir(parents=True, exist_ok=True)
        if s.is_dir():
            shutil.copytree(s, d, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(s, d)
    out = dest / "dist"
    # a copy has no git: the commit it was built from is passed as an sdist build would
    env = dict(os.environ, DEEPLENS_BUILD_COMMIT=BUILD_COMMIT)
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps",
                        "--no-build-isolation", "--no-index", "-q", "-w", str(out)],
                       capture_output=True, text=True, cwd=dest, env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    (wheel,) = out.glob("deeplens_do-*.whl")
    return wheel


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    return build_wheel(tmp_path_factory.mktemp("wheel"))


def test_wheel_carries_lenses_configs_licence_and_entry_point(wheel):
    import deeplens

    names = set(zipfile.ZipFile(wheel).namelist())
    lenses = {p.name for p in (REPO / "data" / "lenses").glob("*.json")}
    configs = {p.relative_to(REPO / "configs").as_posix()
               for p in (REPO / "configs").rglob("*.yaml")}
    assert {f"deeplens/_resources/lenses/{n}" for n in lenses} <= names
    assert {f"deeplens/_resources/configs/{n}" for n in configs} <= names
    assert "deeplens/_resources/configs/experiment/edof.yaml" in names
    info = f"deeplens_do-{deeplens.__version__}.dist-info"
    assert f"{info}/licenses/LICENSE" in names
    meta = zipfile.ZipFile(wheel).read(f"{info}/METADATA").decode()
    assert "License-Expression: MIT" in meta and f"Version: {deeplens.__version__}" in meta
    for extra in ("plot", "design", "train", "dev", "docs"):
        assert f"Provides-Extra: {extra}" in meta
    assert 'Requires-Dist: matplotlib>=3.6; extra == "plot"' in meta
    entry = zipfile.ZipFile(wheel).read(f"{info}/entry_points.txt").decode()
    assert "deeplens = deeplens.cli:main" in entry


def test_checkout_resources_are_the_repository_files(tmp_path, monkeypatch):
    """In a checkout the resources are the repository's own files, found from any directory."""
    from deeplens.optics.io import load_lens
    from deeplens.resources import config_dir, lens_dir, lens_path

    assert lens_dir() == REPO / "data" / "lenses" and config_dir() == REPO / "configs"
    monkeypatch.chdir(tmp_path)
    assert load_lens("double_gauss").surfaces[0].c.numel() == 1
    assert lens_path("cooke_triplet") == REPO / "data" / "lenses" / "cooke_triplet.json"
    with pytest.raises(FileNotFoundError, match="shipped with deeplens: cooke_triplet"):
        load_lens("double_gaus")
    with pytest.raises(FileNotFoundError, match="lens file not found: sub/double_gauss.json"):
        load_lens("sub/double_gauss.json")      # a path with a folder is never a shipped name


def test_version_command(capsys):
    import deeplens
    from deeplens.cli import main

    assert main(["--version"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"deeplens-do {deeplens.__version__}")
    assert f"deeplens at {REPO / 'deeplens'}" in out


def _venv_with_wheel(root: Path, wheel: Path) -> Path:
    """A fresh venv with the wheel installed; this interpreter's packages appended after it."""
    venv = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    py = venv / "bin" / "python"
    r = subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q",
                        "--no-deps", "--no-index", str(wheel)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()"
                           "['purelib'])"], capture_output=True, text=True, check=True)
    Path(site.stdout.strip(), "zz_parent_env.pth").write_text(
        sysconfig.get_paths()["purelib"] + "\n")
    return venv


@pytest.mark.slow
def test_installed_wheel_works_outside_the_checkout(tmp_path, wheel):
    venv = _venv_with_wheel(tmp_path, wheel)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "DEEPLENS_DATA_DIR", "VIRTUAL_ENV")}
    env["OMP_NUM_THREADS"] = "1"

    def run(*args, timeout=600):
        r = subprocess.run([str(venv / "bin" / "deeplens"), *args], cwd=work, env=env,
                           capture_output=True, text=True, timeout=timeout)
        assert r.returncode == 0, f"deeplens {' '.join(args)}:\n{r.stdout}\n{r.stderr}"
        return r.stdout

    version = run("--version")
    assert f"deeplens at {venv}" in version, version       # the installed copy, not the checkout
    assert "EFL 27.4427 mm" in run("report", "double_gauss")
    assert "cooke_triplet" in run("lenses")
    # the commit the wheel was built from (setup.py records it; the checkout has git)
    src = subprocess.run([str(venv / "bin" / "python"), "-c", "from deeplens.build_info import "
                          "describe_source; print(describe_source())"], cwd=work, env=env,
                         capture_output=True, text=True, check=True).stdout
    assert src.strip().endswith(f"commit {BUILD_COMMIT} (recorded at build)"), src
    out = json.loads(run("design", "sensitivity", "--json", "--out", "sens"))
    assert out["fd_max_rel_err"] < 1e-5      # forward-mode AD = central differences
    assert list((work / "sens").glob("*.png"))
    run("train", "experiment=doublet", "sensor.resolution=[16,16]", "data.image_size=32",
        "data.batch_size=2", "data.train_steps_per_epoch=2", "data.val_size=2",
        "data.test_size=2", "render.spp=2", "render.psf_rays=1024", "trainer.max_epochs=1",
        "callbacks.image_logger.psf_rays=256")
    (ckpt,) = (work / "outputs" / "doublet").glob("*/checkpoints/best.ckpt")
    assert ckpt.with_suffix(".lens.json").is_file()
