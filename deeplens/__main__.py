"""``python -m deeplens ...``: the ``deeplens`` command (:mod:`deeplens.cli`)."""

import sys

from .cli import main

sys.exit(main())
