"""The analysis suite against optiland (a test-only oracle) on two lenses.

Lenses: the double Gauss (``data/lenses/double_gauss.json``, conic + a4..a8 on surface 1) and the
Thorlabs ACL5040U asphere (``data/lenses/thorlabs_acl5040u.json``, conic -0.64 and a4; stopped
down here to a 6 mm semi-diameter with fields 0/1/2 deg and sampled 64 x 64 so that its wavefront
changes by < 1/2 wave between pupil samples, as an FFT PSF needs; the full aperture is used for
the OPD).

The optiland model is built from the same lens dictionary, each medium an ideal constant-index
material with our index at the analysed wavelength, every surface with a hard clear aperture of
our semi-diameter, the image plane at optiland's own paraxial image (``image_solve``) and ours at
``image_plane="paraxial"``.  optiland's conventions, checked in its source (0.6.3) and used
unchanged here:

* pupil coordinates are normalised on the paraxial entrance pupil ("paraxial" ray aiming);
  ``aim="real"`` is compared with its "iterative" aiming at the stop centre;
* distortion ("f-tan", rotational model): ``100 (y_chief - s tan θ) / (s tan θ)`` where the
  scale ``s`` comes from a near-axis real chief ray (``H = 1e-10``) on the image surface, i.e.
  the paraxial chief ray: our ``κ`` of ``chief_ray_scale``;
* OPD ("chief_ray" strategy): reference sphere centred on the chief ray's image point with
  radius to the paraxial exit-pupil point on the axis, ``W = (L_chief - L) / λ`` in waves, plus
  the plane-wave launch correction ``n d · (o - o_chief)``; its ``OPD.rms()`` is
  ``sqrt(mean W^2)`` about the chief ray (no piston removal), ours ``rms`` removes the mean, so
  both are compared;
* FFT MTF: ``num_rays x num_rays`` uniform pupil grid clipped to the disk, zero-padded to
  ``grid_size``, ``|FFT(PSF)|`` normalised at zero frequency; frequency step
  ``n' |Δd_⊥| / ((num_rays - 1) λ)`` cycles/mm from the marginal rays' direction cosines,
  tangential = pupil ``y``, sagittal = pupil ``x``.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

optiland = pytest.importorskip("optiland")

import helpers as H  # noqa: E402
import torch  # noqa: E402

from deeplens.analysis.aberrations import distortion, field_curvature  # noqa: E402
from deeplens.analysis.cardinal import cardinal_points, magnification, pupils  # noqa: E402
from deeplens.analysis.diffraction import mtf  # noqa: E402
from deeplens.analysis.wavefront import wavefront  # noqa: E402
from deeplens.optics.io import lens_from_dict  # noqa: E402
from deeplens.optics.materials import get_material  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
WL = 587.5618
N_PUPILS = {"double_gauss": 32, "acl5040u": 64}
N_PUPIL = 32


def _spec(name):
    d = json.loads((REPO / "data" / "lenses" / name).read_text())
    if name.startswith("thorlabs_acl"):
        d["surfaces"][0]["semi_diameter_mm"] = 6.0
        d["fields_deg"] = [0.0, 1.0, 2.0]
    return d


LENSES = {"double_gauss": _spec("double_gauss.json"),
          "acl5040u": _spec("thorlabs_acl5040u.json")}


def _index(material):
    return float(get_material(material).n(torch.tensor(WL, dtype=torch.float64)))


def build_optiland(spec: dict, object_distance=math.inf):
    """An optiland ``Optic`` from a lens dictionary (see the module docstring)."""
    op = H.optiland_optic(spec, _index, object_distance)
    if math.isinf(object_distance):
        op.fields.set_type(field_type="angle")
        for f in spec["fields_deg"]:
            op.fields.add(y=f)
    else:
        op.fields.set_type(field_type="object_height")
        op.fields.add(y=0.0)
        op.fields.add(y=1.0)
    op.wavelengths.add(value=WL / 1000.0, is_primary=True)
    op.image_solve()
    return op


def _quiet(fn, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*a, **k)


def s(v) -> float:
    return float(np.asarray(v, dtype=float).ravel()[0])


@pytest.fixture(scope="module", params=list(LENSES))
def pair(request):
    spec = LENSES[request.param]
    lens = lens_from_dict(spec).to(torch.float64)
    return request.param, spec, lens, _quiet(build_optiland, spec)


def test_cardinal_points_and_pupils(pair):
    name, spec, lens, op = pair
    c = cardinal_points(lens, WL)
    p = op.paraxial
    z = lens.z_vertices()
    z_img = float(z[-1]) + s(op.surfaces[-2].thickness)  # optiland's image surface
    assert float(c.efl) == pytest.approx(s(p.f2()), rel=1e-9)
    assert float(c.front_focal_length) == pytest.approx(s(p.f1()), rel=1e-9)
    assert float(c.front_focal_z) == pytest.approx(s(p.F1()), abs=1e-9)
    assert float(c.front_principal_z) == pytest.approx(s(p.P1()), abs=1e-9)
    assert float(c.front_nodal_z) == pytest.approx(s(p.N1()), abs=1e-9)
    assert float(c.rear_focal_z) - z_img == pytest.approx(s(p.F2()), abs=1e-9)
    assert float(c.rear_principal_z) - z_img == pytest.approx(s(p.P2()), abs=1e-9)
    assert float(c.rear_nodal_z) - z_img == pytest.approx(s(p.N2()), abs=1e-9)
    q = pupils(lens, WL)
    assert float(q.entrance_z) == pytest.approx(s(p.EPL()), abs=1e-9)
    assert float(q.entrance_diameter) == pytest.approx(s(p.EPD()), rel=1e-9)
    assert float(q.exit_z) - z_img == pytest.approx(s(p.XPL()), abs=1e-9)
    assert float(q.exit_diameter) == pytest.approx(s(p.XPD()), rel=1e-9)
    assert float(q.working_fno) == pytest.approx(s(p.FNO()), rel=1e-9)  # EFL/EPD at infinity
    assert float(q.image_na) == pytest.approx(math.sin(math.atan(0.5 / s(p.FNO()))), rel=1e-9)
    assert float(q.image_z) == pytest.approx(z_img, abs=1e-9)


def test_finite_conjugate_magnification(pair):
    name, spec, lens, _ = pair
    op = _quiet(build_optiland, spec, object_distance=250.0)
    m = magnification(lens, WL, object_distance_mm=250.0)
    assert float(m) == pytest.approx(s(op.paraxial.magnification()), rel=1e-9)
    q = pupils(lens, WL, object_distance_mm=250.0)
    z_img = float(lens.z_vertices()[-1]) + s(op.surfaces[-2].thickness)
    assert float(q.image_z) == pytest.approx(z_img, abs=1e-9)
    assert 0 < float(q.object_na) < float(q.image_na)


@pytest.mark.parametrize("aim", ["paraxial", "real"])
def test_distortion(pair, aim):
    name, spec, lens, op = pair
    from optiland.analysis.distortion_strategies import create_distortion_model

    fields = [f for f in spec["fields_deg"] if f > 0]
    fmax = max(spec["fields_deg"])
    ours = distortion(lens, fields, WL, image_plane="paraxial", aim=aim)
    if aim == "real":
        op.ray_tracer.set_aiming("iterative", max_iter=50, tol=1e-13)
    try:
        model = create_distortion_model("paraxial")
        res = _quiet(model.compute, op, np.zeros(len(fields)), np.array(fields) / fmax, WL / 1e3)
        ref = np.asarray(model.percent(res, signed=True), dtype=float)
    finally:
        op.ray_tracer.set_aiming("paraxial")
    assert ours.numpy() == pytest.approx(ref, abs=1e-4)  # % absolute (target: 0.01)
    assert np.abs(ref).max() > 1e-3  # the lens does distort: the comparison has teeth


def _optiland_opd(op, field_norm, n=N_PUPIL):
    from optiland.wavefront import OPD

    o = _quiet(OPD, op, (0.0, field_norm), WL / 1e3, num_rays=n, distribution="uniform")
    d = o.get_data(o.fields[0], o.wavelengths[0])
    return np.asarray(d.opd, dtype=float), np.asarray(d.intensity, dtype=float) > 0, float(o.rms())


def test_opd(pair):
    name, spec, lens, op = pair
    fmax = max(spec["fields_deg"])
    for f in spec["fields_deg"]:
        w = wavefront(lens, f, WL, n=N_PUPILS[name], image_plane="paraxial")
        ref, ok, rms_chief = _optiland_opd(op, f / fmax, N_PUPILS[name])
        inside = ((w.pupil ** 2).sum(-1) <= 1 + 1e-12)
        ours, mask = w.opd[inside].numpy(), w.mask[inside].numpy()
        assert (mask == ok).all(), f"field {f}: vignetted rays differ"
        assert ours[mask] == pytest.approx(ref[ok], abs=1e-6)
        assert math.sqrt((ours[mask] ** 2).mean()) == pytest.approx(rms_chief, abs=1e-3)
        r = ref[ok]
        assert float(w.rms) == pytest.approx(math.sqrt(((r - r.mean()) ** 2).mean()), abs=1e-3)
        assert float(w.pv) == pytest.approx(r.max() - r.min(), abs=1e-3)
        assert float(w.rms) > 0.05  # a real aberration, not zero against zero


def test_opd_full_aperture_asphere():
    """The ACL5040U at its full 25 mm semi-diameter: ~12 waves RMS of (residual) spherical."""
    spec = json.loads((REPO / "data" / "lenses" / "thorlabs_acl5040u.json").read_text())
    lens = lens_from_dict(spec).to(torch.float64)
    op = _quiet(build_optiland, spec)
    w = wavefront(lens, 0.0, WL, n=N_PUPIL, image_plane="paraxial")
    ref, ok, rms_chief = _optiland_opd(op, 0.0)
    r = ref[ok]
    assert float(w.rms) == pytest.approx(math.sqrt(((r - r.mean()) ** 2).mean()), abs=1e-3)
    assert float(w.rms) > 5


def test_diffraction_mtf(pair):
    name, spec, lens, op = pair
    from optiland.mtf import FFTMTF

    fmax = max(spec["fields_deg"])
    for f in spec["fields_deg"]:
        n = N_PUPILS[name]
        m = mtf(lens, f, WL, n=n, image_plane="paraxial")
        o = _quiet(FFTMTF, op, fields=[(0.0, f / fmax)], wavelength=WL / 1e3, num_rays=n,
                   grid_size=2 * n)
        assert m.freq_t.numpy() == pytest.approx(np.asarray(o.freq_tang[0], float), rel=1e-9)
        assert m.freq_s.numpy() == pytest.approx(np.asarray(o.freq_sag[0], float), rel=1e-9)
        assert m.mtf_t.numpy() == pytest.approx(np.asarray(o.mtf[0][0], float), abs=1e-6)
        assert m.mtf_s.numpy() == pytest.approx(np.asarray(o.mtf[0][1], float), abs=1e-6)
        assert 0.02 < float(m.mtf_t[4]) < 0.98


def test_field_curvature(pair):
    name, spec, lens, op = pair
    from optiland.analysis import FieldCurvature

    fc = _quiet(FieldCurvature, op, num_points=3)
    fmax = max(spec["fields_deg"])
    zt, zs = field_curvature(lens, [0.0, 0.5 * fmax, fmax], WL, image_plane="paraxial",
                             aim="paraxial")
    assert zt.numpy() == pytest.approx(np.asarray(fc.data[0][0], float), abs=1e-6)
    assert zs.numpy() == pytest.approx(np.asarray(fc.data[0][1], float), abs=1e-6)
    assert abs(float(zt[-1] - zs[-1])) > 1e-3  # astigmatism at the edge of the field


def test_geometric_mtf_and_strehl(pair):
    """Geometric MTF (optiland: ``scale=False``, the transform of a 257-bin histogram of the same
    uniform-grid spot; ours transforms the ray positions exactly, so the bins' averaging, about
    ``(π ν Δx)²/6`` relative with ``Δx`` = spot extent / 257, leaves a few 1e-3 at 100 cycles/mm)
    and the FFT PSF's Strehl ratio (optiland: peak / 100 of its PSF normalised to 100 for the
    aberration-free pupil)."""
    name, spec, lens, op = pair
    from optiland.mtf import GeometricMTF
    from optiland.psf import FFTPSF

    from deeplens.analysis.diffraction import geometric_mtf, strehl

    fmax = max(spec["fields_deg"])
    f = spec["fields_deg"][-1]
    n = N_PUPILS[name]
    o = _quiet(GeometricMTF, op, fields=[(0.0, f / fmax)], wavelength=WL / 1e3,
               num_rays=n, distribution="uniform", num_points=256, max_freq=100.0,
               scale=False)
    freqs = np.asarray(o.freq, dtype=float)
    g = geometric_mtf(lens, f, freqs, WL, n=n, image_plane="paraxial")
    assert g.mtf_t.numpy() == pytest.approx(np.asarray(o.mtf[0][0], float), abs=0.01)
    assert g.mtf_s.numpy() == pytest.approx(np.asarray(o.mtf[0][1], float), abs=0.01)
    assert float(g.mtf_t[-1]) < 0.9
    p = _quiet(FFTPSF, op, (0.0, f / fmax), WL / 1e3, num_rays=n, grid_size=2 * n)
    ours = float(strehl(lens, f, WL, n=n, image_plane="paraxial"))
    assert ours == pytest.approx(p.strehl_ratio(), abs=1e-6)
    assert ours < 0.9
