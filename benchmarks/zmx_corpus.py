"""Load rate of deeplens' .zmx reader on the real-file corpus (tests/data/zmx_real/).

    OMP_NUM_THREADS=1 python benchmarks/zmx_corpus.py [FOLDER]

Prints, per file, ``loaded`` with the paraxial EFL and EPD (mm), the number of mirrors and of
coordinate breaks (folds, off-axis sections), or the one located line of the refusal, then the
counts.  Point it at another folder of ``.zmx`` files to measure that one.

On the default corpus it also prints, per loaded file, which independent readings confirm its
first-order numbers (``optiland``, ``rayoptics``, or ``none``) and the rate: it runs the two
oracle tests (tests/optics/io/test_zmx_corpus.py::test_loads_with_the_oracles_numbers and
test_zmx_corpus_rayoptics.py::test_rayoptics_confirms_first_order_numbers) and reads their
outcome per file; rayoptics counts for a file only where it confirms all four numbers (not a
file of its ``NOT_CONFIRMED`` list).  ``--no-oracles`` skips them (about two minutes on one core).

On another folder (files the tests have not seen) the oracles run here, file by file, with the
tests' own oracle code (the same helpers, pointed at that folder): optiland's and rayoptics'
readings of the file, given deeplens' refractive indices, must give the same EFL, entrance pupil
diameter and position and back focal point (optiland to 1e-6 relative, rayoptics to 1e-9, as the
tests; rayoptics, which reads neither ``FLOA`` nor a Zernike sag's terms nor a Binary 2 phase,
gets its own marginal ray scaled to the stop's size, the vertex curvature of deeplens' stated
Zernike rule and the Binary 2 phase's thin-lens power as curvature, worked out from the file: test_zmx_corpus_rayoptics._rayoptics; a ``GRID_SAG`` surface, which rayoptics reads as a plane
and optiland refuses, is given to both as the vertex curvature of deeplens' stated rule worked
out from its GDAT/GARR numbers, test_zmx_corpus.grid_sag_vertex_curvatures; a tilted object or
image plane, ``TILTSURF`` on the first or last ``SURF``, is given to optiland, which reads no
tilted ``TILTSURF``, as the flat plane: the numbers compared are first-order data about the axis,
which neither plane's tilt changes, test_zmx_corpus._load_optiland); the oracles read
copies laid out as test_zmx_corpus.oracle_text makes them (an indent common to every line
removed, an old-style WAVL list as WAVM lines: OpTaliX's export); near-afocal systems agree where both focal lengths (and back focal distances) are
beyond 1e12 file units (their powers equal to 1e-12 per unit: the round-off of a vanishing
power), a back focal point also to 1e-6 of the focal length (a focus on the image plane); a
file with coordinate breaks that optiland reads differently is compared once more with every
break zeroed (deeplens' paraxial data follow the local axes, as the corpus test where optiland
declines them), shown as ``optiland(breaks zeroed)``.  Each oracle's first disagreeing quantity,
or why it could not read the file, is printed under the file.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # this checkout's deeplens

from deeplens.optics.io.zmx import ZemaxFileError, read_zmx  # noqa: E402
from deeplens.optics.paraxial import paraxial  # noqa: E402
from deeplens.optics.surfaces import CoordinateBreak  # noqa: E402


REPO = Path(__file__).resolve().parents[1]
ORACLE_TESTS = {
    "optiland": "tests/optics/io/test_zmx_corpus.py::test_loads_with_the_oracles_numbers",
    "rayoptics": "tests/optics/io/test_zmx_corpus_rayoptics.py"
                 "::test_rayoptics_confirms_first_order_numbers",
}


def oracle_confirmations() -> dict[str, list[str]]:
    """``{file name: [oracles whose test passes for it]}`` from one pytest run of both tests."""
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-rA", "-p", "no:cacheprovider",
                          "-p", "no:logging", *ORACLE_TESTS.values()],
                         cwd=REPO, capture_output=True, text=True).stdout
    sys.path.insert(0, str(REPO / "tests/optics/io"))
    from test_zmx_corpus_rayoptics import NOT_CONFIRMED

    confirmed: dict[str, list[str]] = {}
    for oracle, test in ORACLE_TESTS.items():
        for m in re.finditer(rf"^PASSED {re.escape(test)}\[(.+)\]\s*$", out, re.M):
            if oracle == "rayoptics" and m.group(1) in NOT_CONFIRMED:
                continue
            confirmed.setdefault(m.group(1), []).append(oracle)
    return confirmed


def folder_oracles(root: Path):
    """``confirm(name, lens) -> (oracles that confirm, {oracle: why not})`` for the files of
    ``root``: the corpus tests' oracle helpers, pointed at ``root``."""
    import atexit
    import math
    import shutil
    import tempfile

    import pytest

    sys.path.insert(0, str(REPO / "tests/optics/io"))
    import test_zmx_corpus as tc
    import test_zmx_corpus_rayoptics as tr

    # the oracles read copies in the layout they take (tc.oracle_text: an indent common to
    # every line removed, an old-style WAVL list as WAVM lines; the numbers unchanged)
    copies = tempfile.mkdtemp(prefix="zmx_oracles_")
    atexit.register(shutil.rmtree, copies, True)
    tc.CORPUS = tr.CORPUS = tc.oracle_folder(root, copies)

    def optiland(name, lens, tmp):
        s_mm = tc._unit_mm(name)
        try:   # the oracle itself asks optiland for a floating pupil (FLOA): it may decline too
            optic, _ = tc._oracle(name, lens)
            first, ref = optic, name
            if tc._has_decenters(name):
                ref = tc._without_decenters(name, tmp)
                first, _ = tc._oracle(ref, lens)
            if tc._has_gratings(name):
                first, _ = tc._oracle(name, lens, gratings=False)
            if tc._even_r2_terms(name):   # optiland's paraxial trace sees CURV alone
                ref = tc._r2_in_curvature(ref, tmp)
                first, _ = tc._oracle(ref, lens, gratings=not tc._has_gratings(name))
            numbers = tc._first_order(lens, first, s_mm, ref)
        except tc.UnsupportedParaxialGeometryError:
            numbers = None
        bad = "declines paraxial data" if numbers is None else _differs(numbers)
        if bad and any(isinstance(s, CoordinateBreak) for s in lens.surfaces):
            # deeplens' paraxial data follow the local axes, ignoring every break (as the
            # corpus test where optiland declines them): the file with the breaks zeroed
            ref = tc._without_breaks(name, tmp)
            if tc._even_r2_terms(name):
                ref = tc._r2_in_curvature(ref, tmp)
            first, _ = tc._oracle(ref, lens)
            if not _differs(tc._first_order(lens, first, s_mm, ref)):
                return "unbroken"
        return bad or None

    def _differs(numbers):
        for what, (dl, ol) in numbers.items():
            if math.isinf(ol) and math.isinf(dl):
                continue
            if abs(dl - ol) <= max(1e-6 * abs(ol), 1e-9 * max(1.0, abs(dl))):
                continue
            if what in ("EFL", "BFL") and abs(1.0 / dl - 1.0 / ol) <= 1e-12:
                continue   # afocal but for round-off (1 / 1e-12 units) either way: a focus at
                # "infinity", its distance the round-off of a vanishing power
            if what == "BFL" and abs(dl - ol) <= 1e-6 * abs(numbers["EFL"][1]):
                continue   # a focus on the image plane: to 1e-6 of the focal length
            return f"{what} {dl:.6g} vs {ol:.6g}"
        return None

    def rayoptics(name, lens, tmp):
        with pytest.MonkeyPatch.context() as mp:
            opm = tr._rayoptics(name, lens, mp, tmp)
            numbers = tr._numbers(name, lens, opm)
            for what, (dl, ro) in numbers.items():
                if tr._agrees(dl, ro) or (what in ("EFL", "BFL")
                                          and abs(1.0 / dl - 1.0 / ro) <= 1e-12):
                    continue
                if what == "BFL" and abs(dl - ro) <= 1e-9 * abs(numbers["EFL"][1]):
                    continue
                return f"{what} {dl:.6g} vs {ro:.6g}"
        return None

    def confirm(name, lens):
        ok, why = [], {}
        for oracle, check in (("optiland", optiland), ("rayoptics", rayoptics)):
            with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    bad = check(name, lens, Path(tmp))
                except Exception as e:  # noqa: BLE001 - an oracle that cannot read the file
                    bad = f"cannot: {type(e).__name__}: {str(e).splitlines()[0][:60]}" if str(
                        e) else f"cannot: {type(e).__name__}"
            if bad is None or bad == "unbroken":
                ok.append(oracle if bad is None else f"{oracle}(breaks zeroed)")
            else:
                why[oracle] = bad
        return ok, why

    return confirm


def main(folder: str | None = None, oracles: bool = True) -> int:
    root = Path(folder) if folder else REPO / "tests/data/zmx_real"
    by = oracle_confirmations() if oracles and folder is None else None
    if not root.is_dir():
        raise SystemExit(f"zmx_corpus: {root} is not a folder of .zmx files")
    files = sorted(p for p in root.iterdir() if p.suffix.lower() == ".zmx")
    confirm = folder_oracles(root.resolve()) if oracles and folder is not None else None
    if confirm is not None:
        by = {}
    loaded = refused = crashed = confirmed = 0
    counts: dict[str, int] = {}
    for f in files:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                lens = read_zmx(f)
                p = paraxial(lens)
                folds = sum(isinstance(s, CoordinateBreak) for s in lens.surfaces)
                if confirm is not None:
                    ok, why = confirm(f.name, lens)
                    if ok:
                        by[f.name] = ok
                    for o in ok:
                        counts[o.split("(")[0]] = counts.get(o.split("(")[0], 0) + 1
                print(f"{f.name:58s} loaded   EFL {float(p.efl):10.4f}  EPD "
                      f"{float(p.entrance_pupil_diameter):8.4f}  mirrors {len(lens.mirrors)}  "
                      f"breaks {folds}" + (f"  confirmed by {'+'.join(by.get(f.name, ['none']))}"
                                           if by is not None else ""))
                if confirm is not None and why:
                    print(f"{'':58s}          {'not confirmed' if not ok else 'also'}: " + "; ".join(
                        f"{o}: {w}" for o, w in why.items()))
                loaded += 1
                confirmed += by is not None and f.name in by
            except ZemaxFileError as e:
                print(f"{f.name:58s} refused  {str(e).replace(str(f), '')[:110]}")
                refused += 1
            except Exception as e:  # noqa: BLE001 - an unlocated error is what we measure
                print(f"{f.name:58s} CRASH    {type(e).__name__}: {e}")
                crashed += 1
    print(f"\n{loaded} / {len(files)} load, {refused} refused with their location, "
          f"{crashed} unlocated errors")
    if by is not None:
        for o in ORACLE_TESTS:
            n = counts.get(o, 0) if confirm is not None else sum(o in v for v in by.values())
            print(f"{n} / {loaded} loaded files confirmed by {o}")
        print(f"{confirmed} / {loaded} loaded files ({confirmed / max(loaded, 1):.0%}) confirmed by "
              f"an independent reading; {confirmed} / {len(files)} of all files")
    return 1 if crashed else 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", nargs="?", default=None,
                    help="a folder of .zmx files (default: tests/data/zmx_real)")
    ap.add_argument("--no-oracles", action="store_true",
                    help="skip the oracles (optiland, rayoptics)")
    a = ap.parse_args()
    sys.exit(main(a.folder, not a.no_oracles))
