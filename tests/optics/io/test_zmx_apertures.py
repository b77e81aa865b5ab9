"""Zemax aperture decenters (``OBDC``) and model glasses (``V_d = 0``, ``n_d < 1``) read from
``.zmx`` files: the clip is checked against the hit points of an unclipped trace, the writer
round-trips, and what deeplens cannot model is refused with its line."""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from test_zmx import line_of, singlet, write

from deeplens.optics.options import TraceOptions
from deeplens.optics.io import ZemaxFileError, lens_to_dict, read_zmx, write_zmx
from deeplens.optics.materials import ModelGlass
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Aperture
from deeplens.optics.tracer import fused_kind


def _with_field_stop(unit_scale=1.0, clap="CLAP 0 2 0", obdc="OBDC 1 -0.5", extra=()):
    """The singlet with a flat surface in the image-side air gap 10 mm behind the lens, carrying
    ``clap`` and ``obdc`` (lengths divided by ``unit_scale``: 10 for a file in cm)."""
    s = unit_scale
    text = singlet() if s == 1 else singlet(
        unit="CM", curv1=0.2, curv2=-0.05, t=0.5, bfl=4.5, aperture="ENPD 1", diam1=0.8,
        s1_extra=("PARM 1 0", "PARM 2 1e-02", "PARM 3 -2e-02")).replace(
        "DISZ 2\n", "DISZ 0.2\n").replace("DIAM 5 1", "DIAM 0.5 1").replace(
        "DIAM 8 1", "DIAM 0.8 1").replace("DIAM 6 1", "DIAM 0.6 1")
    bfl = "4.5" if s != 1 else "45.0"
    block = ["SURF 4", "  TYPE STANDARD", "  CURV 0.0", f"  DISZ {35.0 / s!r}",
             *[f"  {x}" for x in (clap, obdc, *extra) if x]]
    text = text.replace(f"  DISZ {bfl}\n", f"  DISZ {10.0 / s!r}\n", 1)
    text = text.replace("SURF 4\n", "\n".join(block) + "\nSURF 5\n", 1)
    return text


def _on_axis_rays(lens, n=41):
    """A square grid of on-axis rays filling 99 % of the 10 mm entrance pupil (float64)."""
    g = torch.linspace(-4.95, 4.95, n, dtype=torch.float64)
    x, y = torch.meshgrid(g, g, indexing="ij")
    keep = x * x + y * y <= 4.95 ** 2
    x, y = x[keep], y[keep]
    o = torch.stack([x, y, torch.full_like(x, -1.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(o)
    return Rays(o, d, torch.full(x.shape, 650.0, dtype=torch.float64))


def test_decentred_clear_aperture_clips_about_its_centre(tmp_path):
    """OBDC 1 -0.5 on a CLAP of radius 2: exactly the rays whose hit on that plane lies within
    2 mm of (1, -0.5) pass (the hit points from a trace that clips nothing); the opposite sign,
    or no decenter, would pass another set."""
    lens = read_zmx(write(tmp_path, _with_field_stop())).double()
    i = next(k for k, s in enumerate(lens.surfaces) if isinstance(s, Aperture) and k > 0)
    ap = lens.surfaces[i]
    assert ap.decenter.tolist() == [1.0, -0.5] and fused_kind(lens, i) is None  # runs eager
    rays = _on_axis_rays(lens)
    with torch.no_grad():
        free, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False), record=True)
        clipped = lens.trace(rays)
    x, y = hits[i][..., 0], hits[i][..., 1]

    def inside(dx, dy):
        return free.valid & ((x - dx) ** 2 + (y - dy) ** 2 <= 4.0)

    want = inside(1.0, -0.5)
    assert 0 < int(want.sum()) < int(free.valid.sum())          # the aperture vignettes
    assert torch.equal(clipped.valid, want)
    for wrong in (inside(-1.0, 0.5), inside(-1.0, -0.5), inside(0.0, 0.0)):
        assert not torch.equal(wrong, want)


def test_decenter_is_a_length_in_the_file_unit(tmp_path):
    mm = read_zmx(write(tmp_path, _with_field_stop(), "mm.zmx"))
    cm = read_zmx(write(tmp_path, _with_field_stop(10.0, "CLAP 0 0.2 0", "OBDC 0.1 -0.05"),
                        "cm.zmx"))
    a, b = lens_to_dict(mm), lens_to_dict(cm)
    assert b["surfaces"][3]["decenter_mm"] == pytest.approx([1.0, -0.5], rel=1e-12)
    assert a["surfaces"][3]["decenter_mm"] == [1.0, -0.5]


@pytest.mark.parametrize("clap,obdc", [("CLAP 0 2 0", "OBDC 1 -0.5"),
                                       ("CLAP 0.5 2 0", "OBDC -0.25 0.75"),
                                       ("SQAP 1.5 2.5 0", "OBDC 0.5 0.25")])
def test_decentred_apertures_round_trip(tmp_path, clap, obdc):
    """A decentred circle, annulus (annular CLAP: the obscuration moves with it) and rectangle
    are written back (CLAP/SQAP + OBDC) and read the same, in .zmx and in deeplens' JSON."""
    from deeplens.optics.io import lens_from_dict

    lens = read_zmx(write(tmp_path, _with_field_stop(clap=clap, obdc=obdc)))
    write_zmx(lens, tmp_path / "back.zmx")
    text = (tmp_path / "back.zmx").read_text()
    assert "OBDC " in text
    d = lens_to_dict(lens)
    assert lens_to_dict(read_zmx(tmp_path / "back.zmx")) == d
    assert lens_to_dict(lens_from_dict(d)) == d
    ap = lens.surfaces[3]
    dx, dy = (float(v) for v in obdc.split()[1:])
    assert ap.decenter.tolist() == [dx, dy]
    if clap.startswith("CLAP 0.5"):
        assert float(ap.obscuration) == 0.5


@pytest.mark.parametrize("where,edit,match", [
    ("stop", lambda t: t.replace('  DISZ 2\n  DIAM 5 1 0 0 1 ""\n',
                                 '  DISZ 2\n  DIAM 5 1 0 0 1 ""\n  CLAP 0 5 0\n  OBDC 0.5 0\n', 1),
     "a decentred aperture stop is not supported"),
    ("lens", lambda t: t.replace('  DIAM 8 1 0 0 1 ""\nSURF 4',
                                 '  DIAM 8 1 0 0 1 ""\n  CLAP 1 8 0\n  OBDC 0.5 0\nSURF 4', 1),
     "an annular or obscured decentred aperture on a lens or mirror surface"),
    ("obscuration", lambda t: _with_field_stop(clap="OBSC 0 1 0", obdc="OBDC 0.5 0",
                                               extra=('DIAM 3 1 0 0 1 ""',)),
     "a decentred obscuration"),
])
def test_decenters_deeplens_cannot_model_are_refused_with_their_line(tmp_path, where, edit,
                                                                     match):
    text = edit(singlet()) if where != "obscuration" else edit(None)
    ln = line_of(text, "OBDC")
    with pytest.raises(ZemaxFileError, match=f"t.zmx:{ln}: OBDC on SURF \\d+ .*{match}"):
        read_zmx(write(tmp_path, text))


def test_a_decenter_without_an_aperture_is_reported_and_ignored(tmp_path):
    text = _with_field_stop(clap="", obdc="OBDC 1 -0.5", extra=('DIAM 3 0 0 0 1 ""',))
    ln = line_of(text, "OBDC")
    with pytest.warns(UserWarning, match=f":{ln}: OBDC on SURF 4: .*no aperture"):
        lens = read_zmx(write(tmp_path, text))
    assert not any(isinstance(s, Aperture) and s.decentred for s in lens.surfaces)


def test_model_glass_with_zero_abbe_number_is_non_dispersive(tmp_path):
    """OpticStudio's model glass with V_d = 0 has no dispersion: deeplens' V_d = inf, written
    back as 0."""
    text = singlet(glass="GLAS ___BLANK 1 0 1.6 0 0 0 0 0 0 0")
    lens = read_zmx(write(tmp_path, text))
    m = lens.materials[2]
    assert isinstance(m, ModelGlass) and math.isinf(m.v_d)
    n = m.n(torch.tensor([450.0, 587.5618, 700.0], dtype=torch.float64))
    assert n.tolist() == pytest.approx([1.6, 1.6, 1.6], abs=1e-15)
    write_zmx(lens, tmp_path / "back.zmx")
    assert "GLAS ___BLANK 1 0 1.6 0.0 " in (tmp_path / "back.zmx").read_text()
    assert lens_to_dict(read_zmx(tmp_path / "back.zmx")) == lens_to_dict(lens)


def test_dispersive_model_glass_below_one_is_refused_with_its_line(tmp_path):
    text = singlet(glass="GLAS ___BLANK 1 0 0.9997 50 0 0 0 0 0 0")
    ln = line_of(text, "GLAS ___BLANK")
    with pytest.raises(ZemaxFileError, match=f"t.zmx:{ln}: model glass .*n_d >= 1.*V_d = inf"):
        read_zmx(write(tmp_path, text))


def test_non_dispersive_model_glass_below_one_is_a_relative_index(tmp_path):
    """``GLAS ___BLANK 1 0 0.9997 0``: OpticStudio's indices are relative to air, so a vacuum or
    purge-gas medium is below 1 (lithography patents); the model glass keeps it, at every
    wavelength, and the writer writes it back."""
    text = singlet(glass="GLAS ___BLANK 1 0 0.9997 0 0 0 0 0 0 0")
    lens = read_zmx(write(tmp_path, text))
    m = lens.materials[2]
    assert isinstance(m, ModelGlass) and m.n(193.0) == 0.9997 and m.n(5000.0) == 0.9997
    write_zmx(lens, tmp_path / "back.zmx")
    assert "GLAS ___BLANK 1 0 0.9997 0.0 " in (tmp_path / "back.zmx").read_text()
    assert lens_to_dict(read_zmx(tmp_path / "back.zmx")) == lens_to_dict(lens)


@pytest.mark.parametrize("clap,narrower", [("CLAP 0 4 0", True), ("CLAP 0 5.5 0", False)])
def test_a_clear_aperture_that_cuts_the_entrance_pupil_on_a_flat_stop(tmp_path, clap,
                                                                      narrower):
    """ENPD 10 sizes the flat stop in air (in object space) to radius 5: a CLAP of 4 on it
    vignettes the pupil as in OpticStudio (refused before branch ``stopclap``): the stop is
    read as a flat ``Asphere`` of semi-diameter 5 and clear radius 4
    (``test_zmx_flat_stop_clap.py``); one of 5.5 cuts nothing and the stop stays an
    ``Aperture``."""
    from deeplens.optics.surfaces import Asphere

    text = singlet().replace('  DISZ 2\n  DIAM 5 1 0 0 1 ""\n',
                             f'  DISZ 2\n  DIAM 5 1 0 0 1 ""\n  {clap}\n', 1)
    lens = read_zmx(write(tmp_path, text))
    stop = lens.surfaces[lens.stop_index]
    assert float(stop.semi_diameter) == pytest.approx(5.0)
    if narrower:
        assert type(stop) is Asphere and float(stop.clear_radius) == 4.0
    else:
        assert isinstance(stop, Aperture)


def test_a_stop_inside_the_next_lens_sag_loads(tmp_path):
    """Phone-lens files put the stop 0.3 mm behind the first lens's vertex (DISZ -0.3 after the
    stop): read as written, a virtual stop (``tests/optics/test_virtual_stop.py``)."""
    text = singlet().replace('  DISZ 2\n  DIAM 5 1 0 0 1 ""\n', '  DISZ -0.3\n  DIAM 5 1 0 0 1 ""\n', 1)
    lens = read_zmx(write(tmp_path, text))
    assert float(lens.distances[lens.stop_index + 1]) == -0.3
    write_zmx(lens, tmp_path / "back.zmx")   # and written back as read
    assert lens_to_dict(read_zmx(tmp_path / "back.zmx")) == lens_to_dict(lens)


@pytest.mark.parametrize("obdc", ["OBDC 0 1", "OBDC 0 -1"])
def test_decentred_aperture_vignettes_a_field_as_optiland_does(tmp_path, obdc):
    """At the 5° field a CLAP of 2.5 mm decentred by ±1 mm in y passes a different part of the
    beam: the share of rays that pass and their centroid on the image agree with optiland's
    reading of the same file (its OffsetRadialAperture; hexapolar pupils of 40 rings in both);
    the two signs differ by 0.8 mm in centroid, far beyond the tolerance."""
    import numpy as np
    from test_zmx_corpus import _oracle

    from deeplens.analysis.spot import spot_diagram

    p = write(tmp_path, _with_field_stop(clap="CLAP 0 2.5 0", obdc=obdc))
    lens = read_zmx(p)
    optic, _ = _oracle(p, lens)
    w = float(lens.spec.primary_wavelength_nm)
    with torch.no_grad():
        s = spot_diagram(lens, 5.0, w, "hexapolar:40", pupil="paraxial")
    rays = optic.trace(0.0, 1.0, w / 1000.0, 40, "hexapolar")
    ok = np.asarray(torch.as_tensor(rays.i)) > 0
    y = np.asarray(torch.as_tensor(rays.y))
    assert s.n_rays / s.n_launched == pytest.approx(ok.mean(), abs=0.005)
    assert float(s.centroid[1]) == pytest.approx(y[ok].mean(), abs=2e-3)
    assert abs(float(s.centroid[1]) - 3.72) > 0.3     # the decenter moved the centroid


CORPUS = __import__("pathlib").Path(__file__).resolve().parents[2] / "data" / "zmx_real"


def test_a_clear_aperture_narrower_than_a_lens_surface_stop_vignettes_the_pupil(tmp_path):
    """``optiland_lens2``: ENPD 15 with the stop on the first (aspheric) lens surface, whose
    paraxial stop radius is 7.5 mm, and a CLAP of 6.75 mm there.  As in OpticStudio the pupil
    keeps the size the ENPD gives it (EPD 15, paraxial data unchanged) and the opening is the
    smaller one: exactly the rays that meet the surface within 6.75 mm pass (hit points from a
    trace that clips nothing).  Without the clear aperture the on-axis RMS spot would be 49 %
    larger; with it, it equals optiland's (``test_zmx_corpus``).  Written back as ``CLAP``."""
    from deeplens.analysis.spot import spot_diagram
    from deeplens.optics.paraxial import paraxial

    with pytest.warns(Warning):
        lens = read_zmx(CORPUS / "optiland_lens2.zmx")
    lens = lens.double()
    i = lens.stop_index
    stop = lens.surfaces[i]
    assert float(stop.semi_diameter) == pytest.approx(7.5, rel=1e-12)
    assert float(stop.clear_radius) == 6.75
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(15.0, rel=1e-12)
    assert fused_kind(lens, i) is None   # clipped by the surface's own in_aperture: eager
    g = torch.linspace(-7.4, 7.4, 61, dtype=torch.float64)
    x, y = torch.meshgrid(g, g, indexing="ij")
    keep = x * x + y * y <= 7.4 ** 2
    o = torch.stack([x[keep], y[keep], torch.full_like(x[keep], -1.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(o)
    rays = Rays(o, d, torch.full(o.shape[:1], 587.6, dtype=torch.float64))
    with torch.no_grad():
        free, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False), record=True)
        r = torch.linalg.vector_norm(hits[i][..., :2], dim=-1)
        want = free.valid & (r <= 6.75)
        assert 0 < int(want.sum()) < int(free.valid.sum())   # the clear aperture vignettes
        for opt in (None, TraceOptions(closed_form=False)):
            assert torch.equal(lens.trace(rays, options=opt).valid, want)
        w = float(lens.spec.primary_wavelength_nm)
        with_clap = float(spot_diagram(lens, 0.0, w, "hexapolar:12", pupil="paraxial").rms_radius)
        stop.clear_radius.fill_(math.inf)
        without = float(spot_diagram(lens, 0.0, w, "hexapolar:12", pupil="paraxial").rms_radius)
        stop.clear_radius.fill_(6.75)
    assert without > 1.3 * with_clap
    write_zmx(lens, tmp_path / "rt.zmx")
    assert "CLAP 0 6.75 0" in (tmp_path / "rt.zmx").read_text()
    with pytest.warns(Warning):
        back = read_zmx(tmp_path / "rt.zmx")
    assert lens_to_dict(back)["surfaces"] == lens_to_dict(lens)["surfaces"]
    assert lens_to_dict(lens)["surfaces"][i]["clear_radius_mm"] == 6.75


def test_off_axis_parabola_clips_about_its_decentred_opening(tmp_path):
    """``zmax_37992`` (a 90° off-axis parabola, R = -190.6 mm, reached through a y decenter of
    -190.6 mm): its CLAP of 25.4 mm with OBDC (0, 190.6) is the mirror's off-axis opening.  Of a
    beam wider than the opening, exactly the rays whose hit on the mirror lies within 25.4 mm of
    (0, 190.6) pass (hit points of a trace that clips nothing; the opposite decenter, or a
    centred opening, would pass others); the semi-diameter encloses the opening; the rays that
    pass meet at the parabola's focus (a point at round-off).  Written back as CLAP + OBDC."""
    from deeplens.optics.sampling import field_rays

    with pytest.warns(Warning):
        lens = read_zmx(CORPUS / "zmax_37992.zmx")
    lens = lens.double()
    i = next(k for k, s in enumerate(lens.surfaces) if k in lens.mirrors)
    m = lens.surfaces[i]
    assert m.clear_decenter.tolist() == [0.0, 190.6] and float(m.clear_radius) == 25.4
    assert float(m.semi_diameter) == pytest.approx(216.0, rel=1e-12)
    assert fused_kind(lens, i) is None
    g = torch.linspace(-40.0, 40.0, 41, dtype=torch.float64)
    x, y = torch.meshgrid(g, g, indexing="ij")
    xy = torch.stack([x.reshape(-1), y.reshape(-1)], -1)
    xy = xy[(xy[:, 1] != 0)]   # the central row leaves the mirror inside the image plane
    free_opt = TraceOptions(clip_aperture=False)
    with torch.no_grad():
        w = float(lens.spec.primary_wavelength_nm)
        lens.surfaces[0].semi_diameter.fill_(100.0)   # the stop: let the wide beam through
        rays = field_rays(lens, 0.0, w, xy, -1.0)
        free, hits = lens.trace(rays, options=free_opt, record=True)
        clipped = lens.trace(rays)
        hx, hy = hits[i][..., 0], hits[i][..., 1]

        def inside(cy):
            return free.valid & (hx ** 2 + (hy - cy) ** 2 <= 25.4 ** 2)

        want = inside(190.6)
        assert 0 < int(want.sum()) < int(free.valid.sum())
        assert torch.equal(clipped.valid, want)
        assert not torch.equal(inside(-190.6), want) and not torch.equal(inside(0.0), want)
        out = lens.trace_to_sensor(rays)
        p = out.o[out.valid]
        assert int(out.valid.sum()) == int(want.sum())
        assert float((p - p.mean(0)).norm(dim=-1).max()) < 1e-9   # the parabola's focus
    write_zmx(lens, tmp_path / "rt.zmx")
    assert "OBDC 0.0 190.6" in (tmp_path / "rt.zmx").read_text()


def test_off_axis_mirrors_clip_at_their_decentred_rectangles(tmp_path):
    """``US08011793-1`` (an unobscured four-mirror telescope): three mirrors have a SQAP opening
    decentred by OBDC.  Of a beam wider than the openings, exactly the rays whose hits (of a
    trace that clips nothing) lie within each mirror's rectangle about its decenter pass (the
    opposite decenter would pass others); written back as SQAP + OBDC and read the same."""
    from deeplens.optics.sampling import field_rays

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens = read_zmx(CORPUS / "US08011793-1.zmx")
    lens = lens.double()
    rects = {0: (424.0, 192.0, -397.0), 1: (190.0, 95.0, -156.0), 3: (225.435, 140.0, 140.0)}
    for i, (hx, hy, dy) in rects.items():
        s = lens.surfaces[i]
        assert i in lens.mirrors and fused_kind(lens, i) is None
        assert s.clear_rect.tolist() == [hx, hy] and s.clear_decenter.tolist() == [0.0, dy]
    from deeplens.optics.paraxial import paraxial

    g = torch.linspace(-150.0, 150.0, 31, dtype=torch.float64)   # the entrance pupil: 143 mm
    x, y = torch.meshgrid(g, g, indexing="ij")
    xy = torch.stack([x.reshape(-1), y.reshape(-1)], -1)
    w = float(lens.spec.primary_wavelength_nm)
    with torch.no_grad():
        lens.surfaces[2].semi_diameter.fill_(500.0)   # the stop: let the wide beam through
        rays = field_rays(lens, 16.0, w, xy, float(paraxial(lens).entrance_pupil_z))
        free, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False), record=True)

        def inside(sign):
            ok = free.valid.clone()
            for i, (hx, hy, dy) in rects.items():
                h = hits[i]
                ok &= (h[:, 0].abs() <= hx) & ((h[:, 1] - sign * dy).abs() <= hy)
            return ok

        want = inside(1.0)
        assert 0 < int(want.sum()) < int(free.valid.sum())
        assert torch.equal(lens.trace(rays).valid, want)
        assert not torch.equal(inside(-1.0), want)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens = read_zmx(CORPUS / "US08011793-1.zmx")   # the stop as the file sizes it
    write_zmx(lens, tmp_path / "rt.zmx")
    text = (tmp_path / "rt.zmx").read_text()
    assert "SQAP 424.0 192.0 0" in text and "OBDC 0.0 -397.0" in text
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        back = read_zmx(tmp_path / "rt.zmx")
    assert lens_to_dict(back)["surfaces"] == lens_to_dict(lens)["surfaces"]
    # and through deeplens' own lens file (JSON: clear_rect_mm, clear_decenter_mm)
    from deeplens.optics.io import lens_from_dict

    again = lens_from_dict(lens_to_dict(lens))
    assert lens_to_dict(again) == lens_to_dict(lens)
    assert again.surfaces[0].clear_rect.tolist() == [424.0, 192.0]


def _ring_baffle(ring="OBSC 1.2 2 0"):
    """The singlet with a flat ring baffle (``ring``: OBSC lo hi) in the image-side air gap, its
    plane 10 mm behind the lens, inside a fixed 6 mm opening."""
    return _with_field_stop(clap=ring, obdc="", extra=('DIAM 6 1 0 0 1 ""',))


def test_ring_baffle_blocks_only_its_ring(tmp_path):
    """``OBSC 1.2 2`` on a flat surface in air (a ring baffle): exactly the rays whose hit on
    that plane lies at ρ <= 1.2 or ρ >= 2 (within the 6 mm DIAM) pass (hit points from a trace
    that clips nothing); a central obscuration of 2 mm, or the ring's radii swapped for an
    annular opening, would pass another set.  It traces eager (no fused kind)."""
    lens = read_zmx(write(tmp_path, _ring_baffle())).double()
    i = next(k for k, s in enumerate(lens.surfaces) if isinstance(s, Aperture) and k > 0)
    ap = lens.surfaces[i]
    assert (float(ap.obscuration_inner), float(ap.obscuration)) == (1.2, 2.0)
    assert fused_kind(lens, i) is None
    rays = _on_axis_rays(lens)
    with torch.no_grad():
        free, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False), record=True)
        clipped = lens.trace(rays)
    r2 = hits[i][..., 0] ** 2 + hits[i][..., 1] ** 2
    want = free.valid & ((r2 <= 1.2 ** 2) | (r2 >= 4.0)) & (r2 <= 36.0)
    assert 0 < int((free.valid & ~want).sum()) and int((want & (r2 <= 1.44)).sum()) > 0
    assert torch.equal(clipped.valid, want)
    for wrong in (free.valid & (r2 >= 4.0), free.valid & (r2 >= 1.44) & (r2 <= 4.0)):
        assert not torch.equal(wrong, want)


def test_ring_baffle_round_trips_through_zmx_and_the_lens_file(tmp_path):
    from deeplens.optics.io import lens_from_dict

    lens = read_zmx(write(tmp_path, _ring_baffle()))
    p = tmp_path / "back.zmx"
    write_zmx(lens, p)
    assert "OBSC 1.2 2.0 0" in p.read_text()
    back = read_zmx(p)
    assert lens_to_dict(back) == lens_to_dict(lens)
    d = lens_to_dict(lens)
    e = next(s for s in d["surfaces"] if s.get("obscuration_inner_mm"))
    assert (e["obscuration_inner_mm"], e["obscuration_mm"]) == (1.2, 2.0)
    assert lens_to_dict(lens_from_dict(d)) == d
    # checkpoints keep their keys: the ring's inner radius comes with the lens file
    assert not any(k.endswith("obscuration_inner") for k in lens.state_dict())
    central = read_zmx(write(tmp_path, _ring_baffle("OBSC 0 2 0"), "c.zmx"))
    write_zmx(central, tmp_path / "c2.zmx")
    assert "OBSC 0 2.0 0" in (tmp_path / "c2.zmx").read_text()


@pytest.mark.parametrize("edit,needle,match", [
    (lambda t: t.replace('  DIAM 8 1 0 0 1 ""\nSURF 4', '  DIAM 8 1 0 0 1 ""\n  OBSC 1 2 0\nSURF 4',
                         1), "OBSC 1 2",
     r"SURF 3: OBSC 1 2, a ring obscuration \(a baffle; minimum radius > 0\), on a lens "
     r"surface \(Asphere\) is not supported"),
    (lambda t: _ring_baffle("OBSC 2 1.2 0"), "OBSC 2 1.2",
     r"OBSC on SURF 4: expected 0 <= minimum radius < maximum radius, got 2, 1.2"),
    (lambda t: _ring_baffle("OBSC 1.2 2 0").replace("OBSC 1.2 2 0", "CLAP 0.5 6 0\n  OBSC 1.2 2 0"),
     "OBSC 1.2 2", r"OBSC on SURF 4: the surface already has an obscuration \(an annular CLAP"),
])
def test_ring_obscurations_deeplens_cannot_model_are_refused_with_their_line(tmp_path, edit,
                                                                            needle, match):
    text = edit(singlet())
    ln = line_of(text, needle)
    with pytest.raises(ZemaxFileError, match=f"t.zmx:{ln}: {match}"):
        read_zmx(write(tmp_path, text))


def test_aperture_ring_obscuration_constructor_errors():
    with pytest.raises(ValueError, match="a ring obscuration needs 0 < inner radius"):
        Aperture(5.0, obscuration=2.0, obscuration_inner=2.5)
    ring = Aperture(5.0, obscuration=2.0, obscuration_inner=1.0)
    x = torch.tensor([0.0, 1.0, 1.5, 2.0, 4.0, 5.5], dtype=torch.float64)
    assert ring.opening.contains(x, torch.zeros_like(x)).tolist() == [
        True, True, False, True, True, False]
