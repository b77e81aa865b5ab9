"""The writer: a :class:`~deeplens.optics.lens.Lens` -> a sequential Zemax ``.zmx`` file that
:func:`~.zmx_read.read_zmx` reads back to the same prescription.

Numbers are written with ``repr`` (shortest round-trip text), so a lens read, written and read
again is the same bit for bit; what the reader maps onto deeplens (:mod:`.zmx`) is written back
the same way: element misalignments as ``COORDBRK`` pairs, :class:`CoordinateBreak` surfaces as
``COORDBRK`` surfaces, mirrors as ``GLAS MIRROR``, apertures as ``DIAM``/``CLAP``/``OBSC``/
``SQAP``/``OBDC``, glasses by catalogue name (or as model glasses).
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from ..errors import ZemaxFileError
from ..lens import Lens
from ..materials import GLASS_TABLE, Air, Material, ModelGlass
from ..surfaces import Aperture, CoordinateBreak
from ..surfaces.base import (clear_ellipse_of, clear_rect_of, obscuration_ellipse_of,
                            obscuration_spider_of)
from .agf import AGFGlass
from .surface_handlers import FORMATS
from .vendor_glass import BuchdahlGlass
from .zmx_glass import _PLACEHOLDER_ND_VD, BUILTIN_CATALOGUES
from .zmx_system import rotationally_symmetric, zemax_tilts

__all__ = ["write_zmx"]


def _f(v: float) -> str:
    return repr(float(v))


# deeplens catalogue name -> the name Zemax's MISC catalogue uses
_ZEMAX_NAME = {"FUSED_SILICA": "F_SILICA", "PC": "POLYCARB"}


def _glass_line(m: Material, cats: list) -> str | None:
    """The ``GLAS`` line of medium ``m`` (``None`` for air); adds its catalogue to ``cats``."""
    if isinstance(m, Air):
        return None
    if isinstance(m, (AGFGlass, BuchdahlGlass)):
        if m.catalogue and m.catalogue not in cats:
            cats.append(m.catalogue)
        try:
            nd_vd = f"{_f(m.nd)} {_f(m.vd)}"
        except ValueError:   # not defined at the d line (an infrared glass): OpticStudio's
            # placeholder, as its own files write GERMANIUM (readers take the catalogue's glass)
            nd_vd = f"{_f(_PLACEHOLDER_ND_VD[0])} {_f(_PLACEHOLDER_ND_VD[1])}"
        return f"GLAS {m.name} 0 0 {nd_vd} 0 0 0 0 0 0"
    name = m.name.upper()
    rec = GLASS_TABLE.get(name)
    is_entry = rec is not None and (not isinstance(m, ModelGlass) or m.to_spec() == rec.name)
    if is_entry:
        zname = _ZEMAX_NAME.get(name, name)
        for cat, names in BUILTIN_CATALOGUES.items():
            if zname in names:
                if cat not in cats:
                    cats.append(cat)
                return f"GLAS {zname} 0 0 {_f(m.nd)} {_f(m.vd)} 0 0 0 0 0 0"
    if isinstance(m, ModelGlass):
        # a named entry of deeplens' table that is a model glass (SK1, F15, SK16: the paper
        # authors' n_d/V_d) keeps its name on a model-glass line (code 1)
        # (as does a model glass a file named: GLAS NAME 1 0 n_d V_d)
        named = m.name != m.to_spec() or is_entry
        label = m.name.upper() if named and len(m.name.split()) == 1 and "/" not in m.name \
            else "___BLANK"
        v_d = 0.0 if math.isinf(m.v_d) else m.v_d   # OpticStudio's non-dispersive model glass
        return f"GLAS {label} 1 0 {_f(m.n_d)} {_f(v_d)} 0 0 0 0 0 0"
    raise ZemaxFileError(f"material {m.name!r} ({type(m).__name__}) has no Zemax catalogue name; "
                         f"use a catalogue glass or an n_d/V_d model glass")


def _object_na(lens: Lens) -> float:
    """The object-space NA ``n sin θ`` of an object-space telecentric lens: the cone about
    each chief ray whose slope ``tan θ = r_EP / |s + z_EP|`` is the paraxial entrance pupil's
    radius over its distance from the object (the inverse of the reader's ``OBNA``)."""
    from ..paraxial import media_indices, paraxial

    with torch.no_grad():
        par = paraxial(lens)
        n0 = float(media_indices(lens)[0])
        d = abs(float(lens.spec.object_distance_mm) + float(par.entrance_pupil_position))
        return n0 * math.sin(math.atan(0.5 * float(par.entrance_pupil_diameter) / d))


def write_zmx(lens: Lens, path, encoding: str = "utf-8") -> None:
    """Write ``lens`` as a sequential Zemax ``.zmx`` file that :func:`read_zmx` reads back.

    Args:
        lens: the lens (current parameter values).
        path: output file.
        encoding: ``"utf-8"`` (default) or ``"utf-16"`` (OpticStudio's own, with byte-order mark).

    Raises:
        ZemaxFileError: a surface or material with no Zemax equivalent (B-spline, rectangular
            aperture, XY polynomial with ``b != 0``, more than 7 aspheric terms), or a
            misalignment tilting one element about both x and y.
    """
    spec = lens.spec
    out = ["VERS 170912 299 123456", "MODE SEQ", f"NAME {lens.name}", "UNIT MM X W X CM MR CPMM"]
    telecentric = getattr(lens, "object_telecentric", False)
    if telecentric:
        out.append(f"OBNA {_f(_object_na(lens))} 0")
    elif spec.aperture_type == "epd":
        out.append(f"ENPD {_f(spec.aperture_value)}")
    elif spec.aperture_type == "fno":
        out.append(f"FNUM {_f(spec.aperture_value)} 0")
    else:
        out.append("FLOA")
    if getattr(lens, "ray_aiming", False):
        out.append("RAIM 0 2 1 1 0 0 0 0 0 1")   # real ray aiming, as the file it came from
    cats: list[str] = []
    body: list[str] = []
    nsurf = 0

    def surf(lines):
        nonlocal nsurf
        body.append(f"SURF {nsurf}")
        body.extend("  " + ln for ln in lines)
        nsurf += 1

    def glas(m, extra):
        g = _glass_line(m, cats)
        if g:
            extra.append(g)

    od = float(spec.object_distance_mm)
    tilt = getattr(lens, "object_tilt", (0.0, 0.0))
    obj = ["TYPE STANDARD", "CURV 0.0", f"DISZ {'INFINITY' if math.isinf(od) else _f(od)}"]
    if tilt != (0.0, 0.0):   # OpticStudio's Tilted surface as the object plane
        obj = ["TYPE TILTSURF", "CURV 0.0", f"PARM 1 {_f(tilt[0])}", f"PARM 2 {_f(tilt[1])}",
               obj[-1]]
    glas(lens.materials[0], obj)
    surf(obj)
    with torch.no_grad():
        n = len(lens.surfaces)
        crossing = {i for i in range(n) if lens.hit_backwards(i) or lens.hit_backwards(i, True)}
        elem_of = {}
        for e, (a, b) in enumerate(lens.elements):
            for i in range(a, b + 1):
                elem_of[i] = e
        for i, s in enumerate(lens.surfaces):
            e = elem_of[i]
            a, b = lens.elements[e]
            mis = lens.misalignments[e]
            tilted = not mis.is_identity() and any(
                float(v) != 0 for v in (mis.dx, mis.dy, mis.tilt_x, mis.tilt_y))
            d = (float(mis.dx), float(mis.dy), math.degrees(float(mis.tilt_x)),
                 math.degrees(float(mis.tilt_y)))
            if tilted and d[2] != 0 and d[3] != 0:
                if not all(rotationally_symmetric(s_) for s_ in lens.surfaces[a:b + 1]):
                    raise ZemaxFileError(f"element {e} (surfaces {a}-{b}) is tilted about both x "
                                         f"and y and is not rotationally symmetric: OpticStudio's "
                                         f"x-then-y tilts cannot express deeplens' R_y R_x",
                                         surfaces=range(a, b + 1))
                d = d[:2] + zemax_tilts(*d[2:])
            if tilted and i == a:
                surf(["TYPE COORDBRK", "CURV 0.0", "DISZ 0"] +
                     [f"PARM {k + 1} {_f(v)}" for k, v in enumerate(d)] +
                     ["PARM 5 0", "PARM 6 0"])
            after = float(lens.distances[i + 1]) if i + 1 < n else float(lens.d_sensor)
            if isinstance(s, CoordinateBreak):   # a fold or an off-axis section
                if tilted:
                    raise ZemaxFileError(f"surface {i}: a coordinate break inside a misaligned "
                                         f"element has no .zmx equivalent", surfaces=(i,))
                surf(FORMATS.for_surface(s).write_zmx(s, i) + [f"DISZ {_f(after)}"])
                continue
            inner = sum(float(lens.distances[j]) for j in range(a + 1, b + 1))
            gap = -inner if tilted and i == b else after   # back to the first vertex
            lines = _surface_lines(s, i, lens.stop_index == i)
            if i in crossing:
                # a surface of a gap crossed backwards (Lens.backward_gaps): its semi-diameter
                # as an automatic one (DIAM flag 0, OpticStudio's footprint), which is what the
                # reader opts such a gap in from (zmx_read._cross_backwards_where_the_beam_passes)
                lines = [ln.replace(" 1 0 0 1 \"\"", " 0 0 0 1 \"\"", 1)
                         if ln.startswith("DIAM ") else ln for ln in lines]
            lines.append(f"DISZ {_f(gap)}")
            if i in lens.mirrors:
                lines.append("GLAS MIRROR 0 0 0 0 0 0 0 0 0 0 0")
            elif lens.materials[i + 1].graded:
                # written with its surface's record (GRINSUR1: io.zmx_grin), never as a glass
                if getattr(s, "medium", None) is not lens.materials[i + 1]:
                    raise ZemaxFileError(f"surface {i}: the graded medium after it "
                                         f"({lens.materials[i + 1].name}) has a .zmx record "
                                         f"only with its own surface (a GradientSurface "
                                         f"holding it: GRINSUR1)", surfaces=(i,))
            else:
                glas(lens.materials[i + 1], lines)
            surf(lines)
            if tilted and i == b:
                surf(["TYPE COORDBRK", "CURV 0.0", f"DISZ {_f(inner + after)}"] +
                     [f"PARM {k + 1} {_f(-v)}" for k, v in enumerate(d)] +
                     ["PARM 5 0", "PARM 6 1"])
    img = ["TYPE STANDARD", "CURV 0.0", "DISZ 0"]
    if lens.sensor_semi_diameter is not None:
        img.append(f"DIAM {_f(lens.sensor_semi_diameter)} 1 0 0 1 \"\"")
    surf(img)
    nf, nw = len(spec.fields_deg), len(spec.wavelengths_nm)
    out.append("GCAT " + " ".join(cats or ["SCHOTT"]))
    if tilt[1] != 0:
        # an object plane tilted about x: the fields' object points, where they lie
        # (sampling.object_point; the reader's zmx_system.object_height_fields inverts it)
        s_obj = float(spec.object_distance_mm)
        out.append(f"FTYP 1 {1 if telecentric else 0} {nf} {nw} 0 0 0")
        if telecentric:
            fields = [-s_obj * math.tan(math.radians(float(f))) for f in spec.fields_deg]
        else:
            from ..paraxial import paraxial
            from ..sampling import object_point

            with torch.no_grad():
                z_ep = float(paraxial(lens).entrance_pupil_z)
            fields = [float(object_point(lens, math.radians(float(f)), z_ep, s_obj)[1])
                      for f in spec.fields_deg]
    elif telecentric:
        # object heights (FTYP 1) with telecentric object space (second value 1): the fields'
        # object points, -s tan θ (sampling.field_rays; the reader's object_height_fields)
        s_obj = float(spec.object_distance_mm)
        out.append(f"FTYP 1 1 {nf} {nw} 0 0 0")
        fields = [0.0 - s_obj * math.tan(math.radians(float(f))) for f in spec.fields_deg]
    else:
        out.append(f"FTYP 0 0 {nf} {nw} 0 0 0")
        fields = spec.fields_deg
    out.append("XFLN " + " ".join("0" for _ in spec.fields_deg))
    out.append("YFLN " + " ".join(_f(f) for f in fields))
    for k, w in enumerate(spec.wavelengths_nm, start=1):
        out.append(f"WAVM {k} {_f(float(w) / 1000.0)} 1")
    prim = [float(w) for w in spec.wavelengths_nm]
    pw = float(spec.primary_wavelength_nm)
    if pw in prim:
        out.append(f"PWAV {prim.index(pw) + 1}")
    else:
        raise ZemaxFileError(f"the primary wavelength {pw} nm is not one of the lens's "
                             f"wavelengths {prim}: Zemax's PWAV picks one of them")
    text = "\n".join(out + body) + "\n"
    Path(path).write_text(text, encoding=encoding)


def _surface_lines(s, i, is_stop) -> list[str]:
    """The records of surface ``i`` after its ``SURF`` line: ``STOP``, then what its type's
    handler in the file-format registry writes (:mod:`.surface_handlers`), with the ``SQAP`` of
    a rectangular clear aperture and the ``ELAP``/``ELOB`` of an elliptical one or an elliptical
    obscuration on a type whose own records do not write them
    (:func:`~deeplens.optics.surfaces.base.set_clear_rect`, ``set_clear_ellipse``,
    ``set_obscuration_ellipse``)."""
    handler = FORMATS.for_surface(s)
    if handler is None or not handler.writes_zmx():
        raise ZemaxFileError(f"surface {i}: {type(s).__name__} has no .zmx equivalent",
                             surfaces=(i,))
    lines = (["STOP"] if is_stop else []) + handler.write_zmx(s, i)
    if (isinstance(s, Aperture) and not is_stop and s.shape == "circle"
            and not any(ln.startswith(("CLAP", "ELOB", "SPID")) for ln in lines)):
        # an opening that is not the stop: OpticStudio clips a flat surface only on a surface
        # aperture (a fixed DIAM there is drawn, never clips): its circle is a CLAP (not
        # beside an ELOB or a SPID, the surface's one aperture: the DIAM is drawn, the reader
        # sizes it)
        lines.append(f"CLAP 0 {float(s.semi_diameter)!r} 0")
    rect = clear_rect_of(s)
    if rect is not None and not any(ln.startswith("SQAP") for ln in lines):
        lines.append(f"SQAP {_f(rect[0])} {_f(rect[1])} 0")
    ell = clear_ellipse_of(s)   # ELAP, ELOB (set_clear_ellipse, set_obscuration_ellipse)
    if ell is not None and not any(ln.startswith("ELAP") for ln in lines):
        lines.append(f"ELAP {_f(ell[0])} {_f(ell[1])} 0")
    obs = obscuration_ellipse_of(s)
    if obs is not None and not any(ln.startswith("ELOB") for ln in lines):
        lines.append(f"ELOB {_f(obs[0])} {_f(obs[1])} 0")
    spi = obscuration_spider_of(s)   # SPID (set_obscuration_spider), the surface's one aperture
    if spi is not None:
        others = [ln.split()[0] for ln in lines
                  if ln.startswith(("CLAP", "SQAP", "ELAP", "ELOB", "OBSC", "OBDC"))]
        if others or spi[2] != 0.0:
            why = (f"beside {', '.join(others)} (one aperture type per surface)" if others else
                   f"whose first arm is not along +x (angle {math.degrees(spi[2]):g} deg)")
            raise ZemaxFileError(f"surface {i}: a spider obscuration {why} has no Zemax record "
                                 f"here", surfaces=(i,))
        lines.append(f"SPID {_f(spi[0])} {spi[1]} 0")
    return lines
