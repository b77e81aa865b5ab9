"""OpticStudio's Fresnel surface (``TYPE FRESNELS``): a plane substrate that refracts (or
reflects) about the normal of its facet profile, an even asphere (``CURV``, ``CONI``,
``PARM 1..8``), read as :class:`~deeplens.optics.surfaces.Fresnel` (Zemax guide, A seventh
unseen set; OpticStudio's short-course sample ``sc_fresnel1``).

Checked against closed forms: a ray parallel to the axis at height ``h`` meets the plane at
``(0, h, 0)`` and leaves at ``-(θ_i - θ_t)`` to the axis, ``sin θ_i = c h``, ``sin θ_t = c h / n``
(refraction about the sphere's normal above the hit), or at ``π - 2 θ_i`` from ``+z`` on a
mirror; a Fresnel singlet's EFL is ``1 / ((n − 1)(c + 2 α_1))``; rayoptics' reading of the file
(which takes ``FRESNELS`` for its base sphere, given the folded ``r²`` curvature as for an even
asphere) confirms EFL, EPD, pupil and back focus.
"""

from __future__ import annotations

import math

import pytest
import torch
from test_zmx import write
from zmx_blocks import surf as _surf, zmx_file

from deeplens.optics.errors import ZemaxFileError
from deeplens.optics.io import write_zmx
from deeplens.optics.paraxial import paraxial
from deeplens.optics.surfaces import Fresnel
from deeplens.optics.surfaces.fresnel import FACET_REFRACTION
from helpers import read_zmx_quiet

F64 = torch.float64
C, A1, N = 0.01, 0.001, 1.5     # facet curvature (1/mm), its r² term (1/mm), the glass index

def _hits(heights):
    h = torch.tensor(heights, dtype=F64)
    x = torch.stack([torch.zeros_like(h), h, torch.zeros_like(h)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand_as(x)
    return h, x, d


def test_refraction_about_the_facet_normal_on_the_plane():
    """``d' = (0, -sin(θ_i - θ_t), cos(θ_i - θ_t))`` for every height (to 1e-15), whereas the
    plane's own normal would leave the rays undeviated."""
    surf = Fresnel(C, 40.0).double()
    h, x, d = _hits([-30.0, -5.0, 0.0, 1.0, 12.5, 35.0])
    valid = torch.ones_like(h, dtype=torch.bool)
    d2, ok, _ = FACET_REFRACTION(surf, x, d, 1.0, N, 587.56, valid, torch.zeros_like(h), False)
    ti = torch.asin(C * h)
    tt = torch.asin(C * h / N)
    want = torch.stack([torch.zeros_like(h), -torch.sin(ti - tt), torch.cos(ti - tt)], -1)
    assert bool(ok.all())
    assert float((d2 - want).abs().max()) < 1e-15
    assert float((d2 - d).abs().max()) > 0.05       # the facets deviate the rays


def test_reflection_about_the_facet_normal_on_a_mirror():
    """A concave facet profile (c < 0) on a flat mirror: ``d' = (0, -sin 2θ, -cos 2θ)`` with
    ``sin θ = |c| h`` towards the axis (a focusing mirror of focal length 1/(2|c|))."""
    surf = Fresnel(-C, 40.0).double()
    h, x, d = _hits([-20.0, 3.0, 30.0])
    valid = torch.ones_like(h, dtype=torch.bool)
    d2, ok, _ = FACET_REFRACTION(surf, x, d, 1.0, 1.0, 587.56, valid, torch.zeros_like(h), True)
    t = torch.asin(C * h)
    want = torch.stack([torch.zeros_like(h), -torch.sin(2 * t), -torch.cos(2 * t)], -1)
    assert bool(ok.all())
    assert float((d2 - want).abs().max()) < 1e-15


def _singlet(parm9=None):
    glass = f"___BLANK 1 0 {N} 0 0 0 0 0 0 0"
    phi = (N - 1.0) * (C + 2.0 * A1)
    fres = _surf("FRESNELS", curv=C, parms=[A1, 1e-8], disz=2.0, glas=glass, stop=True,
                 diam=5.0)
    if parm9 is not None:
        fres.insert(-2, f"  PARM 9 {parm9!r}")
    blocks = [_surf(disz="INFINITY"), fres, _surf(disz=1.0 / phi - 2.0 / N, diam=5.0), _surf()]
    return zmx_file(blocks, name="fresnel"), phi


def _read(p):
    return read_zmx_quiet(p).double()


def test_fresnel_singlet_file(monkeypatch, tmp_path):
    """A Fresnel singlet (``CURV 0.01``, ``PARM 1`` = 0.001, ``PARM 2`` = 1e-8, n = 1.5, then a
    plane): EFL ``1/((n − 1)(c + 2 α_1))`` = 166.67 mm (with the ``r²`` term on ``r¹``, as a
    misplaced index would put it, 200 mm); a real ray 0.01 mm off the axis crosses it within
    1e-6 mm of the paraxial focus; the writer's ``FRESNELS`` reads back to the same surface, and
    rayoptics confirms EFL, EPD, pupil and back focus."""
    import test_zmx_corpus as tc
    import test_zmx_corpus_rayoptics as tr

    text, phi = _singlet()
    write(tmp_path, text)
    lens = _read(tmp_path / "t.zmx")
    surf = lens.surfaces[0]
    assert isinstance(surf, Fresnel)
    assert surf.even_coefficients == pytest.approx([A1, 1e-8], rel=1e-15)
    par = paraxial(lens)
    assert float(par.efl) == pytest.approx(1.0 / phi, rel=1e-12)

    from deeplens.optics.rays import Rays

    o = torch.tensor([[0.0, 0.01, -1.0]], dtype=F64)
    d = torch.tensor([[0.0, 0.0, 1.0]], dtype=F64)
    with torch.no_grad():
        out = lens.trace(Rays(o, d, torch.full((1,), 587.5618, dtype=F64)))
    z_cross = -float(out.o[0, 1] / out.d[0, 1] * out.d[0, 2])    # from the last vertex
    assert z_cross == pytest.approx(float(par.bfl), abs=1e-6)

    write_zmx(lens, tmp_path / "w.zmx")
    back = _read(tmp_path / "w.zmx")
    assert isinstance(back.surfaces[0], Fresnel)
    assert back.surfaces[0].to_dict() == surf.to_dict()
    assert float(paraxial(back).efl) == pytest.approx(1.0 / phi, rel=1e-12)

    monkeypatch.setattr(tc, "CORPUS", tmp_path)
    monkeypatch.setattr(tr, "CORPUS", tmp_path)
    assert tc._even_r2_terms("t.zmx") == {1: A1}
    (tmp_path / "ro").mkdir()
    opm = tr._rayoptics("t.zmx", lens, monkeypatch, tmp_path / "ro")
    for what, (dl, ro) in tr._numbers("t.zmx", lens, opm).items():
        assert tr._agrees(dl, ro), f"rayoptics {what}: deeplens {dl!r} vs {ro!r}"


def test_unread_parameter_is_refused_on_its_line(tmp_path):
    text, _ = _singlet(parm9=0.5)
    write(tmp_path, text)
    with pytest.raises(ZemaxFileError, match=r"FRESNELS PARM 9 = 0.5 is not read") as e:
        _read(tmp_path / "t.zmx")
    assert e.value.line == text.splitlines().index("  PARM 9 0.5") + 1


def test_paraxial_power_is_the_facet_profile_vertex_curvature():
    """``paraxial_curvature`` = ``c + 2 α_1`` whatever the conic and higher terms."""
    surf = Fresnel(C, 10.0, conic=-0.7, coefficients=[A1, 3e-6, -1e-9])
    assert float(surf.paraxial_curvature()) == pytest.approx(C + 2 * A1, rel=1e-15)
    assert math.isclose(float(surf.sag(torch.tensor(3.0), torch.tensor(4.0))), 0.0)


def test_facet_parameter_gradients_match_central_differences():
    """The refracted directions' y components (weighted, at heights across the aperture) as a
    function of the facet curvature, conic and the r², r⁴ terms: autograd against central
    differences in float64 (step 1e-6 relative; truncation O(h²) ~ 1e-12, round-off ~ eps/h
    ~ 1e-10 relative)."""
    surf = Fresnel(C, 40.0, conic=-0.5, coefficients=[A1, 2e-7]).double()
    h, x, d = _hits([-30.0, -5.0, 1.0, 12.5, 35.0])
    w = torch.tensor([0.3, -1.0, 2.0, 0.7, -0.4], dtype=F64)
    valid = torch.ones_like(h, dtype=torch.bool)

    def loss():
        d2, ok, _ = FACET_REFRACTION(surf, x, d, 1.0, N, 587.56, valid, torch.zeros_like(h),
                                     False)
        assert bool(ok.all())
        return (w * d2[:, 1]).sum() + (w * w * d2[:, 2]).sum()

    params = {"c": surf.facet.c, "k": surf.facet.k, "a2": surf.facet.a[1],
              "a4": surf.facet.a[3]}
    for prm in params.values():
        prm.requires_grad_(True)     # frozen until unfrozen (make_param)
    grads = torch.autograd.grad(loss(), list(params.values()))
    for (name, prm), g in zip(params.items(), grads):
        step = 1e-6 * max(abs(float(prm)), 1e-3)
        with torch.no_grad():
            prm += step
            up = float(loss())
            prm -= 2 * step
            down = float(loss())
            prm += step
        fd = (up - down) / (2 * step)
        assert abs(fd) > 1e-6, name                      # the parameter moves the directions
        assert float(g) == pytest.approx(fd, rel=1e-5), name
