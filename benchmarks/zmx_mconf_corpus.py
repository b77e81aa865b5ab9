"""Every configuration of the multi-configuration ``.zmx`` files of a folder, against an
independent reading.

    OMP_NUM_THREADS=1 python benchmarks/zmx_mconf_corpus.py DIR

For each file with ``MNUM n`` (n > 1) and each configuration ``k``:

* deeplens reads it with ``read_zmx(path, config=k)`` (its :mod:`~deeplens.optics.io.zmx_mconf`),
  or refuses it with a located error (printed with its line and feature);
* a test-only applier that shares no code with deeplens' (tests/optics/io/zmx_mconf_apply.py)
  rewrites the file's own records with configuration ``k``'s operand values and drops the
  ``MNUM`` block: a single-configuration file;
* ``same``: deeplens' reading of that single-configuration file (no operand involved) is the
  same lens as configuration ``k`` (``lens_to_dict`` equal: every surface, tilt, glass, gap,
  field, wavelength and aperture) with the same EFL, BFL, EPD and entrance-pupil position (to
  1e-12 relative);
* ``= the saved records``: the configuration is the same lens as the file with its ``MNUM``
  block cut (the saved records hold one configuration, the active one: a check of the rows'
  reading against the file itself; older files write ``MNUM n`` without saying which);
* ``oracles``: optiland's and rayoptics' readings of that single-configuration file confirm
  configuration ``k``'s EFL, EPD, entrance-pupil position and back focal point, with the corpus
  tests' own oracle code (benchmarks/zmx_corpus.py ``folder_oracles``: each oracle gets deeplens'
  indices at the primary wavelength, so glass data are not what is compared; ``same`` checks
  the glass names).

A configuration is **confirmed** when ``same`` holds and at least one oracle confirms it.  The
summary line counts configurations loaded / confirmed / refused with their location.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))                      # this checkout's deeplens
sys.path.insert(0, str(REPO / "benchmarks"))
sys.path.insert(0, str(REPO / "tests/optics/io"))

from deeplens.optics.io import lens_to_dict  # noqa: E402
from deeplens.optics.io.agf import decode_zemax_text  # noqa: E402
from deeplens.optics.io.zmx import ZemaxFileError, read_zmx  # noqa: E402
from deeplens.optics.paraxial import paraxial  # noqa: E402
from zmx_corpus import folder_oracles  # noqa: E402
from zmx_mconf_apply import NotApplied, configurations, single_configuration  # noqa: E402


def _numbers(lens) -> dict[str, float]:
    import torch

    p = paraxial(lens.to(torch.float64))
    return {"EFL": float(p.efl), "BFL": float(p.bfl), "EPD": float(p.entrance_pupil_diameter),
            "EP position": float(p.entrance_pupil_z) - float(lens.z_vertices()[0])}


def _same(a: dict, b: dict) -> str | None:
    for k, x in a.items():
        y = b[k]
        if not (x == y or (math.isinf(x) and math.isinf(y))
                or abs(x - y) <= 1e-12 * max(1.0, abs(x), abs(y))):
            return f"{k} {x:.9g} vs {y:.9g}"
    return None


def _unnamed(d: dict) -> dict:
    """``lens_to_dict``'s tree without the lens's ``name``."""
    return {k: v for k, v in d.items() if k != "name"}


def _first_difference(a, b, where="") -> str:
    """The first key path where two ``lens_to_dict`` trees differ, with both values."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b), key=str):
            if a.get(k) != b.get(k):
                return _first_difference(a.get(k), b.get(k), f"{where}.{k}")
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            if x != y:
                return _first_difference(x, y, f"{where}[{i}]")
    return f"{where}: {str(a)[:60]} vs {str(b)[:60]}"


def _read(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(path, **kw)


def main(folder: str) -> int:
    root = Path(folder)
    files = sorted(p for p in root.iterdir() if p.suffix.lower() == ".zmx"
                   and configurations(p)[0] > 1)
    tot = loaded = confirmed = refused = crashed = 0
    files_saved_checked = files_saved_match = 0
    causes: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        confirm = folder_oracles(tmp.resolve())
        for f in files:
            n, active = configurations(f)
            print(f"{f.name}  (MNUM {n} {active})")
            # the saved records alone (the file with its MNUM block cut): the configuration
            # they hold must be one of the configurations read (the rows' reading checked on
            # the file itself; OpticStudio's older files write MNUM n without the active one)
            text = decode_zemax_text(f)
            (tmp / "saved.zmx").write_text(text[:text.index("\nMNUM") + 1])
            try:
                saved = lens_to_dict(_read(tmp / "saved.zmx"))
            except ZemaxFileError:
                saved = None
            matches_saved = 0
            for k in range(1, n + 1):
                tot += 1
                head = f"  config {k}"
                try:
                    lens = _read(f, config=k)
                except ZemaxFileError as e:
                    refused += 1
                    what = (e.message if hasattr(e, "message") else str(e))[:150]
                    print(f"{head}  refused  line {e.line} {e.feature}: {what}")
                    key = f"{e.feature}"
                    causes[key] = causes.get(key, 0) + 1
                    continue
                except Exception as e:  # noqa: BLE001 - an unlocated error is what we measure
                    crashed += 1
                    print(f"{head}  CRASH    {type(e).__name__}: {str(e)[:120]}")
                    continue
                loaded += 1
                num = _numbers(lens)
                try:
                    name = f"{f.stem}_c{k}.zmx"
                    (tmp / name).write_text(single_configuration(f, k))
                except NotApplied as e:
                    print(f"{head}  loaded   EFL {num['EFL']:.6g}; the applier cannot: {e}")
                    continue
                try:
                    single = _read(tmp / name)
                    same = _same(num, _numbers(single))
                    # (the name aside: a file without a NAME record is named after the file,
                    # and the single-configuration copy's file name differs)
                    a, b = _unnamed(lens_to_dict(lens)), _unnamed(lens_to_dict(single))
                    if same is None and a != b:
                        same = "lens_to_dict differs: " + _first_difference(a, b)
                except ZemaxFileError as e:
                    same = f"single-configuration file refused: line {e.line} {e.feature}"
                is_saved = saved is not None and saved == lens_to_dict(lens)
                matches_saved += is_saved
                ok, why = confirm(name, lens)
                good = same is None and bool(ok)
                confirmed += good
                print(f"{head}  loaded   EFL {num['EFL']:12.6g}  EPD {num['EPD']:10.6g}  "
                      f"same {'yes' if same is None else 'NO'}  oracles "
                      f"{'+'.join(ok) or 'none'}  {'CONFIRMED' if good else ''}"
                      f"{'  (= the saved records)' if is_saved else ''}")
                if same is not None:
                    print(f"{'':14s}same: {same}")
                if why and not ok:
                    print(f"{'':14s}" + "; ".join(f"{o}: {w}" for o, w in why.items()))
            if saved is not None:
                files_saved_checked += 1
                files_saved_match += matches_saved > 0
                if not matches_saved:
                    print("  the saved records equal no configuration read")
    print(f"\n{len(files)} files, {tot} configurations: {loaded} loaded, {confirmed} confirmed "
          f"(same + an oracle), {refused} refused with their location, {crashed} unlocated")
    print(f"saved records (the file without its MNUM block) equal one of the configurations "
          f"read: {files_saved_match} of {files_saved_checked} files whose records deeplens "
          f"reads")
    if causes:
        print("refusals by feature: " + ", ".join(f"{k} {v}" for k, v in sorted(causes.items())))
    return 1 if crashed else 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", help="a folder of .zmx files (those with MNUM n > 1 are read)")
    sys.exit(main(ap.parse_args().folder))
