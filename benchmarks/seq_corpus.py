"""Load rate of deeplens' CODE V reader on a folder of real ``.seq`` files, and rayoptics'
confirmation of the loaded ones.

    OMP_NUM_THREADS=1 python benchmarks/seq_corpus.py [FOLDER] [--no-oracle]

FOLDER defaults to tests/data/codev_real.  Per file: ``loaded`` with the paraxial EFL and EPD
(mm) and the number of mirrors, then whether rayoptics' own reading of the same file
(``rayoptics.codev.cmdproc``, a test-only oracle) confirms the first-order numbers: the EFL, the
entrance pupil diameter (EPD) and position from the file's surface 1 (ENP), and the rear focal
point from the image plane (BFP), each to float64 round-off (1e-9 relative), rayoptics being
given deeplens' refractive indices (the oracle code is tests/optics/io/codev_oracle.py, the
corpus test's own; a file without RDM, which deeplens reads in radius mode and rayoptics in
curvature mode, is given to rayoptics with ``RDM Y``, and marked so); or the one located line of
the refusal.  A decentred or tilted lens (coordinate breaks) is confirmed by real rays instead:
its surfaces must lie where rayoptics' do (vertices, orientations and curvatures in the
object-space frame) and the same rays (4 per field, given in object space) must land on the
image surface at the same points in the same directions, to float64 round-off
(``codev_oracle.ray_landings``, ``ray_agrees``).  Each verdict names the kind of confirmation:
``paraxial`` or ``real rays``.  Then the counts: loaded / confirmed / disagree / refused (and
unlocated errors, which should not exist).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))                          # this checkout's deeplens
sys.path.insert(0, str(REPO / "tests" / "optics" / "io"))   # the corpus test's oracle

from deeplens.optics.errors import LensFileError  # noqa: E402
from deeplens.optics.io.codev import read_seq  # noqa: E402
from deeplens.optics.paraxial import paraxial  # noqa: E402


def _by_rays(f, lens, ray_landings, ray_agrees) -> tuple[bool, str]:
    """A decentred lens: ``(confirmed, verdict)`` from real rays (module docstring)."""
    try:
        r = ray_landings(f, lens)
    except AssertionError as e:   # the surfaces do not lie where rayoptics' do
        return False, f"DISAGREE {e}"
    if r["failed"]:
        return False, f"DISAGREE rays traced by one side only: {r['failed']}"
    if not r["rays"]:
        return False, "DISAGREE no ray traced by both"
    text = (f"{r['rays']} rays, landings within {r['dp']:.1e}, directions within "
            f"{r['dd']:.1e}")
    if not ray_agrees(r["dp"], r["dd"], r["length"]):
        return False, f"DISAGREE real rays: {text}"
    return True, f"confirmed, real rays ({text})"


def main(folder: str | None = None, oracle: bool = True) -> int:
    root = Path(folder) if folder else REPO / "tests/data/codev_real"
    if not root.is_dir():
        raise SystemExit(f"seq_corpus: {root} is not a folder of .seq files")
    files = sorted(p for p in root.iterdir() if p.suffix.lower() == ".seq")
    if oracle:
        from codev_oracle import agrees, has_rdm, numbers, ray_agrees, ray_landings
    loaded = confirmed = disagree = refused = crashed = unconfirmed = no_rdm = 0
    for f in files:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                lens = read_seq(f)
                p = paraxial(lens)
            except LensFileError as e:
                print(f"{f.name:28s} refused  {str(e).replace(str(f), '')[:110]}")
                refused += 1
                continue
            except Exception as e:  # noqa: BLE001 - an unlocated error is what we measure
                print(f"{f.name:28s} CRASH    {type(e).__name__}: {e}")
                crashed += 1
                continue
        loaded += 1
        verdict = ""
        if oracle:
            try:
                if any(s.interaction.changes_frame for s in lens.surfaces):
                    ok, verdict = _by_rays(f, lens, ray_landings, ray_agrees)
                else:
                    nums = numbers(f, lens)
                    bad = [f"{q} {dl:.10g} vs {ro:.10g}" for q, (dl, ro) in nums.items()
                           if not agrees(dl, ro)]
                    ok = not bad
                    verdict = ("confirmed, paraxial (EFL, EPD, ENP, BFP)" if ok
                               else "DISAGREE " + "; ".join(bad))
                if ok:
                    confirmed += 1
                else:
                    disagree += 1
                if not has_rdm(f):   # rayoptics' own default is curvature mode
                    verdict += " [no RDM: radius mode, rayoptics given RDM Y]"
                    no_rdm += 1
            except Exception as e:  # noqa: BLE001 - the oracle cannot read it
                unconfirmed += 1
                verdict = f"rayoptics cannot: {type(e).__name__}: {str(e)[:60]}"
        print(f"{f.name:28s} loaded   EFL {float(p.efl):11.4f}  EPD "
              f"{float(p.entrance_pupil_diameter):9.4f}  mirrors {len(lens.mirrors)}  {verdict}")
    print(f"\n{len(files)} files: {loaded} loaded / {confirmed} confirmed / {disagree} disagree / "
          f"{refused} refused" + (f" / {unconfirmed} not read by rayoptics" if unconfirmed else "")
          + (f" / {crashed} unlocated errors" if crashed else "")
          + (f"\n({no_rdm} of the loaded files have no RDM line: read as radii with a warning, "
             f"rayoptics given RDM Y)" if no_rdm else ""))
    return 1 if crashed else 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", nargs="?", default=None,
                    help="a folder of .seq files (default: tests/data/codev_real)")
    ap.add_argument("--no-oracle", action="store_true", help="skip rayoptics")
    a = ap.parse_args()
    sys.exit(main(a.folder, not a.no_oracle))
