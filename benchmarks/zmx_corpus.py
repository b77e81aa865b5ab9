"""Load rate of deeplens' .zmx reader on the real-file corpus (tests/data/zmx_real/).

    OMP_NUM_THREADS=1 python benchmarks/zmx_corpus.py [FOLDER]

Prints, per file, ``loaded`` with the paraxial EFL and EPD (mm), the number of mirrors and of
coordinate breaks (folds, off-axis sections), or the one located line of the refusal, then the
counts.  Point it at another folder of ``.zmx`` files to measure that one.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # this checkout's deeplens

from deeplens.optics.io.zmx import ZemaxFileError, read_zmx  # noqa: E402
from deeplens.optics.paraxial import paraxial  # noqa: E402
from deeplens.optics.surfaces import CoordinateBreak  # noqa: E402


def main(folder: str | None = None) -> int:
    root = Path(folder) if folder else Path(__file__).resolve().parents[1] / "tests/data/zmx_real"
    if not root.is_dir():
        raise SystemExit(f"zmx_corpus: {root} is not a folder of .zmx files")
    files = sorted(p for p in root.iterdir() if p.suffix.lower() == ".zmx")
    loaded = refused = crashed = 0
    for f in files:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                lens = read_zmx(f)
                p = paraxial(lens)
                folds = sum(isinstance(s, CoordinateBreak) for s in lens.surfaces)
                print(f"{f.name:58s} loaded   EFL {float(p.efl):10.4f}  EPD "
                      f"{float(p.entrance_pupil_diameter):8.4f}  mirrors {len(lens.mirrors)}  "
                      f"breaks {folds}")
                loaded += 1
            except ZemaxFileError as e:
                print(f"{f.name:58s} refused  {str(e).replace(str(f), '')[:110]}")
                refused += 1
            except Exception as e:  # noqa: BLE001 - an unlocated error is what we measure
                print(f"{f.name:58s} CRASH    {type(e).__name__}: {e}")
                crashed += 1
    print(f"\n{loaded} / {len(files)} load, {refused} refused with their location, "
          f"{crashed} unlocated errors")
    return 1 if crashed else 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", nargs="?", default=None,
                    help="a folder of .zmx files (default: tests/data/zmx_real)")
    sys.exit(main(ap.parse_args().folder))
