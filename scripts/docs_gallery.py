"""MkDocs hook: the analysis gallery of docs/guide/analysis.md drawn by today's command at
every build, so that the pictures a reader sees are what ``deeplens plot`` makes now (they used
to be PNGs committed once and left behind by later plotting changes).

For each kind in :data:`KINDS` it runs, in this process::

    deeplens plot double_gauss --kind KIND --wavelengths 587.5618,486.1327,656.2725 -o PNG

into a temporary folder and adds the PNG to the site as ``img/double_gauss_KIND.png`` (a
generated file: nothing is written into ``docs/``, so ``mkdocs serve`` does not rebuild in a
loop).  A failing command fails the build with its message.  Registered in ``mkdocs.yml``
under ``hooks:``.
"""

from __future__ import annotations

import contextlib
import io
import tempfile
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File

LENS = "double_gauss"
WAVELENGTHS = "587.5618,486.1327,656.2725"
KINDS = ("layout", "spot", "fan", "opd", "field", "distortion", "psf", "mtf", "ee")


def gallery_argv(kind: str, png: str) -> list[str]:
    """The ``deeplens`` arguments that draw one picture (the command the guide shows)."""
    return ["plot", LENS, "--kind", kind, "--wavelengths", WAVELENGTHS, "-o", png]


def on_files(files, config):
    from deeplens.cli import main

    out = Path(tempfile.mkdtemp(prefix="deeplens-gallery-"))
    for kind in KINDS:
        png = out / f"{LENS}_{kind}.png"
        log = io.StringIO()
        with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            status = main(gallery_argv(kind, str(png)))
        if status not in (0, None) or not png.is_file():
            raise PluginError(f"docs gallery: `deeplens {' '.join(gallery_argv(kind, 'PNG'))}` "
                              f"failed (status {status}):\n{log.getvalue()}")
        uri = f"img/{png.name}"
        old = files.get_file_from_path(uri)
        if old is not None:
            files.remove(old)
        files.append(File.generated(config, uri, abs_src_path=str(png)))
    return files
