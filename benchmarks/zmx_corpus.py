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
out from its GDAT/GARR numbers, test_zmx_corpus.grid_sag_vertex_curvatures; an Extended
Polynomial, ``XPOLYNOM``, which neither reads, is given to both as the sphere of its vertex
curvature ``CURV + (A_x² + A_y²) / R_n²`` worked out from its XDAT terms for first-order data,
test_zmx_corpus.xpolynom_vertex_curvatures; an Extended Odd Asphere, ``XOSPHERE``, which
optiland does not read and rayoptics reads without its normalisation radius and with CURV alone
in its paraxial model, is given to rayoptics as ``A_i / R_n^i`` on ``r^i`` with the vertex
curvature ``CURV + 2 A_2 / R_n²`` (test_zmx_corpus_rayoptics._rayoptics); a two-point
hologram, ``HOLOGRM1``/``HOLOGRM2``, which neither reads (optiland refuses the type, rayoptics
reads the bare substrate), is given to rayoptics as the thin-lens power of its construction
beams' phase at the vertex, worked out from PARM 1-8 and CURV by
test_zmx_corpus_rayoptics._hologram_powers: on a mirror as the curvature that reflects the same,
between equal media as rayoptics' ideal thin lens.  What that confirms for a hologram file: the
records as deeplens reads them (the points in lens units, λ_c in µm, the order, the mirror) and
the paraxial power of deeplens' stated phase (the Zemax guide, Holograms), so the first-order
numbers; not the real-ray law (checked against rayoptics' HolographicElement on synthetic
holograms in tests/optics/surfaces/test_hologram.py) nor which sense each construction beam has,
which no oracle reads: that rests on OpticStudio's sample files putting the image on the other
construction point; a FLOA stop without
DIAM, which the file alone does not size, is given deeplens' stop radius as its DIAM in the
oracles' copy, test_zmx_corpus.floating_stop_text; a tilted object or
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

A lenslet array (``TYPE USERSURF US_ARRAY.DLL``), which neither oracle reads, is given to both as
its on-axis lenslet (the ``STANDARD`` surface of its ``CURV``: lenslet_stand_in_text), shown as
``optiland(on-axis lenslet stand-in)`` (likewise rayoptics): that confirms the reading of everything
else and that deeplens' paraxial data are the on-axis lenslet's, not the other lenslets' layout
(pinned by OpticStudio's stored semi-diameters, tests/optics/io/test_zmx_lenslet_array.py).

GRIN files (``GRINSUR1``, gradient-index media), which neither oracle traces, are confirmed in
two parts, shown as ``optiland(GRIN stand-in + real rays)`` (likewise rayoptics): (1) each oracle
reads the file with every GRIN slab replaced by a homogeneous stand-in with the same paraxial
matrix (grin_stand_in_text: the same thickness in a model glass of index ``L / B``, the two
faces' curvatures changed to add the powers ``(1 − A) / B`` and ``(1 − D) / B``), given deeplens'
indices, and must give the GRIN lens's EFL, entrance pupil and back focal point to the usual
tolerances; (2) deeplens' real-ray focal length of the loaded file (parallel rays at 2e-3 and
1e-3 of the pupil radius, Richardson-extrapolated to the axis) must equal its paraxial EFL to
the stated error estimate (grin_real_ray_check; on the OpticStudio sample ``GRIN interconnect``
2.0632128047 vs 2.0632128151 mm, estimate 7e-8).  What this confirms: the reading of everything
but the medium (object, aperture, stop, the other surfaces, image distance) by an independent
reader, and that deeplens' traced rays agree with its paraxial matrix.  What it does not: the
slab's matrix itself comes from deeplens (its closed form, checked against pygrin and a
closed-form trace in tests/optics/test_grin.py), and that OpticStudio's Gradient 1 index is
``n0 + nr2 r²`` rests on its manual (and, for that one sample, on its image size, which
deeplens' marginal ray meets to 5e-9 mm: test_grin.py).
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
from deeplens.optics.surfaces import CoordinateBreak, LensletArray  # noqa: E402


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
            if tc._has_gratings(name) or tc._has_xpolynom(name):
                # an Extended Polynomial: the sphere of its vertex curvature, as a Q-type's
                # in the corpus test (optiland's paraxial trace sees the base radius alone)
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
        # the oracles' copy of the file as it is now (a caller may write files into ``root``
        # after this folder was set up: benchmarks/zmx_mconf_corpus.py's one-configuration files)
        if (root / name).exists():
            (tc.CORPUS / name).write_text(tc.oracle_text(tc.decode_zemax_text(root / name)))
        if any(m.graded for m in lens.materials):
            return confirm_grin(name, lens)
        ok, why = [], {}
        stop = tc.floating_stop_text((tc.CORPUS / name).read_text(), lens, tc._unit_mm(name))
        if stop is not None:   # FLOA, a stop without DIAM: the copy gets deeplens' stop size
            (tc.CORPUS / name).write_text(stop)
        tag = ""
        if any(isinstance(s, LensletArray) for s in lens.surfaces):
            # neither oracle reads US_ARRAY.DLL: each lenslet array becomes its on-axis lenslet
            (tc.CORPUS / name).write_text(lenslet_stand_in_text((tc.CORPUS / name).read_text()))
            tag = "(on-axis lenslet stand-in)"
        for oracle, check in (("optiland", optiland), ("rayoptics", rayoptics)):
            with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    bad = check(name, lens, Path(tmp))
                except Exception as e:  # noqa: BLE001 - an oracle that cannot read the file
                    bad = f"cannot: {type(e).__name__}: {str(e).splitlines()[0][:60]}" if str(
                        e) else f"cannot: {type(e).__name__}"
            if bad is None or bad == "unbroken":
                ok.append((oracle if bad is None else f"{oracle}(breaks zeroed)") + tag)
            else:
                why[oracle] = bad
        return ok, why

    def confirm_grin(name, lens):
        """A file with gradient-index media (module docstring, "GRIN files"): each oracle reads
        the file with every GRIN slab replaced by its homogeneous stand-in and must give
        deeplens' numbers of the GRIN lens; the confirmation also needs deeplens' real-ray
        focal length to agree with its paraxial one (:func:`grin_real_ray_check`)."""
        real_bad = grin_real_ray_check(lens)
        stand_in = name[:-4] + "__grin_stand_in.zmx"
        (tc.CORPUS / stand_in).write_text(grin_stand_in_text(
            (tc.CORPUS / name).read_text(), lens, tc._unit_mm(name)))
        sub = read_zmx(tc.CORPUS / stand_in)
        ok, why = [], {}

        def opt(tmp):
            optic, _ = tc._oracle(stand_in, sub)
            return _differs(tc._first_order(lens, optic, tc._unit_mm(name), stand_in))

        def ray(tmp):
            with pytest.MonkeyPatch.context() as mp:
                opm = tr._rayoptics(stand_in, sub, mp, tmp)
                for what, (dl, ro) in tr._numbers(stand_in, lens, opm).items():
                    if not tr._agrees(dl, ro):
                        return f"{what} {dl:.6g} vs {ro:.6g}"
            return None

        for oracle, check in (("optiland", opt), ("rayoptics", ray)):
            with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    bad = check(Path(tmp))
                except Exception as e:  # noqa: BLE001 - an oracle that cannot read the file
                    bad = f"cannot: {type(e).__name__}: {str(e).splitlines()[0][:60]}"
            bad = bad or real_bad
            if bad is None:
                ok.append(f"{oracle}(GRIN stand-in + real rays)")
            else:
                why[oracle] = bad
        return ok, why

    return confirm


def lenslet_stand_in_text(text: str) -> str:
    """The file ``text`` with every ``TYPE USERSURF US_ARRAY.DLL`` block (a lenslet array,
    :class:`~deeplens.optics.surfaces.LensletArray`) made the ``STANDARD`` surface of its own
    ``CURV``: the lenslet on the axis, whose curvature deeplens' paraxial data use (odd counts
    only are read: a lenslet sits on the vertex); its ``PARM`` lines dropped.  Neither oracle
    reads the DLL, so what this confirms is the reading of everything else and that deeplens'
    paraxial data are the on-axis lenslet's; the layout of the other lenslets rests on the
    stored semi-diameters (tests/optics/io/test_zmx_lenslet_array.py).  Every other record is
    the file's."""
    out, in_array = [], False
    for ln in text.splitlines():
        if re.match(r"SURF\s+\d+", ln):
            in_array = False
        if re.match(r"\s+TYPE\s+USERSURF\s+US_ARRAY\.DLL\b", ln, re.I):
            in_array = True
            out.append("  TYPE STANDARD")
            continue
        if in_array and re.match(r"\s+(PARM|PPAR)\s", ln):
            continue
        out.append(ln)
    return "\n".join(out) + "\n"


def grin_stand_in_text(text: str, lens, s_mm: float) -> str:
    """The file ``text`` with every ``GRINSUR1`` slab of ``lens`` (its reading) replaced by a
    homogeneous one with the same paraxial matrix: the ``GRINSUR1`` block becomes a ``STANDARD``
    surface into a non-dispersive model glass of index ``n' = L / B`` (the same thickness ``L``),
    its curvature and the next block's curvature changed so that their powers add
    ``φ1 = (1 − A) / B`` and ``φ2 = (1 − D) / B`` (``(A, B, C, D)`` the slab's matrix on
    ``(y, n u)``, :meth:`~deeplens.optics.grin.GradedMedium.paraxial_transfer`): refraction by
    ``φ2``, a gap of reduced thickness ``B`` and refraction by ``φ1`` multiply to that matrix
    (``AD − BC = 1``).  Every other record is the file's."""
    import torch

    w = float(lens.spec.primary_wavelength_nm)
    n = [float(m.n(w)) for m in lens.materials]
    grin = [k for k, m in enumerate(lens.materials) if m.graded]   # media after surface k - 1
    lines = text.splitlines()
    starts = [j for j, ln in enumerate(lines) if re.match(r"SURF\s+\d+", ln)]
    blocks = [j for j in starts if any(re.match(r"\s+TYPE\s+GRINSUR1\b", lines[q])
                                       for q in range(j + 1, next((t for t in starts if t > j),
                                                                  len(lines))))]
    if len(blocks) != len(grin):
        raise ValueError("the GRINSUR1 blocks are not the lens's graded media")
    for j, k in zip(blocks, grin):
        a = k - 1                                   # the GRIN surface; a + 1 the exit one
        med = lens.materials[k]
        length = lens.distances[a + 1].detach()
        with torch.no_grad():
            A, B, C, D = (float(v) for v in med.paraxial_transfer(length, n[k]))
        n_sub = float(length) / B
        c1 = float(lens.surfaces[a].c) if hasattr(lens.surfaces[a], "c") else 0.0
        c2 = float(lens.surfaces[a + 1].c) if hasattr(lens.surfaces[a + 1], "c") else 0.0
        p1 = c1 * (n[k] - n[k - 1]) + (1 - A) / B
        p2 = c2 * (n[k + 1] - n[k]) + (1 - D) / B
        c1s, c2s = p1 / (n_sub - n[k - 1]), p2 / (n[k + 1] - n_sub)
        end = next((t for t in starts if t > j), len(lines))
        nxt = next((t for t in starts if t > end), len(lines))
        out = []
        for q in range(j + 1, end):
            if re.match(r"\s+PARM\s", lines[q]):
                continue
            if re.match(r"\s+TYPE\s+GRINSUR1\b", lines[q]):
                out += ["  TYPE STANDARD", f"  GLAS ___BLANK 1 0 {n_sub!r} 0 0 0 0 0 0 0"]
                continue
            if re.match(r"\s+CURV\s", lines[q]):
                out.append(f"  CURV {c1s * s_mm!r} 0 0 0 0 \"\"")
                continue
            out.append(lines[q])
        lines[j + 1:end] = out
        shift = len(out) - (end - j - 1)
        end, nxt = end + shift, nxt + shift
        starts = [t + shift if t > j else t for t in starts]
        for q in range(end + 1, nxt):
            if re.match(r"\s+CURV\s", lines[q]):
                lines[q] = f"  CURV {c2s * s_mm!r} 0 0 0 0 \"\""
    return "\n".join(lines) + "\n"


#: the real-ray focal length of a GRIN file is taken at these fractions of the entrance pupil
#: radius (a parallel ray at height h: EFL(h) = -h / tan u'; EFL(h) - EFL(0) ~ h²)
GRIN_RAY_HEIGHTS = (2e-3, 1e-3)


def grin_real_ray_check(lens, verbose: bool = False):
    """``None`` when deeplens' real-ray focal length of ``lens`` (parallel rays at two small
    heights, Richardson-extrapolated to the axis, at the file's step and at a quarter of it)
    agrees with its paraxial EFL to the error estimate ``|EFL(h) − EFL(h/2)| / 3`` (the h⁴ term
    left by the extrapolation, bounded by the h² term's size) plus the integration's
    ``|EFL(Δs) − EFL(Δs/4)|`` plus 1e-12 relative; else the disagreement, as text."""
    import math

    import torch

    from deeplens.optics.rays import Rays

    lens = lens.double()
    p = paraxial(lens)
    efl, r = float(p.efl), 0.5 * float(p.entrance_pupil_diameter)
    z0 = float(lens.z_vertices()[0]) - 1.0
    w = float(lens.spec.primary_wavelength_nm)
    media = [m for m in lens.materials if m.graded]
    steps = [m.step_mm for m in media]

    def focal(h):
        rays = Rays(torch.tensor([[0.0, h, z0]], dtype=torch.float64),
                    torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64),
                    torch.tensor([w], dtype=torch.float64))
        out = lens.trace(rays)
        if not bool(out.valid.all()):
            return math.nan
        return -h / float(out.d[0, 1] / out.d[0, 2])

    def extrapolated():
        f1, f2 = (focal(c * r) for c in GRIN_RAY_HEIGHTS)
        return (4 * f2 - f1) / 3, abs(f1 - f2) / 3

    try:
        f_file, est = extrapolated()
        for m, s in zip(media, steps):
            m.step_mm = s / 4
        f_fine, _ = extrapolated()
    finally:
        for m, s in zip(media, steps):
            m.step_mm = s
    tol = est + abs(f_file - f_fine) + 1e-12 * abs(efl)
    if verbose:
        print(f"real-ray EFL {f_file!r} paraxial {efl!r} estimate {tol:.3g}")
    if not abs(f_file - efl) <= tol:
        return f"real-ray EFL {f_file:.10g} vs paraxial {efl:.10g} (estimate {tol:.2g})"
    return None


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
