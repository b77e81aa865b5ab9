"""Build hook (all metadata is in pyproject.toml): the wheel carries the repository's default
lenses (data/lenses/*.json) and Hydra configs (configs/**/*.yaml) as package data under
deeplens/_resources/, where deeplens.resources finds them with importlib.resources.  The
checkout keeps one copy of each file; an editable install reads them from the checkout."""

import json
import os
import shutil
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
#: (folder in the checkout, files, folder inside the installed package)
RESOURCES = [("data/lenses", "*.json", "deeplens/_resources/lenses"),
             ("configs", "**/*.yaml", "deeplens/_resources/configs")]


class BuildPyWithResources(build_py):
    def run(self):
        super().run()
        if self.editable_mode:      # an editable install reads the checkout's files
            return
        for src, pattern, dst in RESOURCES:
            files = sorted((HERE / src).glob(pattern))
            if not files:
                raise FileNotFoundError(f"setup.py: no {pattern} under {HERE / src} (an sdist "
                                        f"without them? see MANIFEST.in)")
            for f in files:
                target = Path(self.build_lib) / dst / f.relative_to(HERE / src)
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(f, target)
        # the commit the wheel was built from (deeplens.build_info): an evaluation's table
        # names it when it runs outside a checkout.  From git, else $DEEPLENS_BUILD_COMMIT (a
        # build from an sdist or a copy of the sources); nothing when neither says
        record = None
        try:
            commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=HERE,
                                    capture_output=True, text=True, timeout=10)
            dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                                   cwd=HERE, capture_output=True, text=True, timeout=10)
            if commit.returncode == 0 and commit.stdout.strip():
                record = {"commit": commit.stdout.strip(), "modified": bool(dirty.stdout.strip())}
        except (OSError, subprocess.SubprocessError):
            pass
        if record is None and os.environ.get("DEEPLENS_BUILD_COMMIT"):
            record = {"commit": os.environ["DEEPLENS_BUILD_COMMIT"], "modified": False}
        if record is not None:
            target = Path(self.build_lib) / "deeplens/_resources/build.json"
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(json.dumps(record))


setup(cmdclass={"build_py": BuildPyWithResources})
