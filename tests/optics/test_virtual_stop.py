"""A stop plane inside a lens's sag (a *virtual* stop): the ray's line is clipped where it crosses
the stop plane (either sign of ``t``) and the next surface is met from where the ray was.

The oracles: which rays pass is the crossing height of each ray's line at the stop plane,
computed here in closed form; where they go is the same lens traced without the stop; the
paraxial numbers and the on-axis spot of a small ``.zmx`` with ``DISZ -0.3`` on the ``STOP`` are
optiland's reading of the same file."""

import math
import warnings

import pytest
import torch

from deeplens.analysis.spot import spot_diagram
from deeplens.optics.io.zmx import read_zmx
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Aperture, Asphere

R_STOP = 1.5
D_AFTER_STOP = -0.3   # the front vertex 0.3 mm before the stop plane: the stop lies in its sag


def _singlet(with_stop: bool) -> Lens:
    """A biconvex singlet; with the stop at z = 0, 0.3 mm *behind* its front vertex (inside
    the front surface's sag: the rim reaches z = +0.016 mm at r = 2.5 mm)."""
    front, back = Asphere(0.1, 2.5), Asphere(-0.05, 2.5)
    glass = ModelGlass(1.5168, 64.17)
    if with_stop:
        return Lens([Aperture(R_STOP), front, back], [Air(), Air(), glass, Air()],
                    [0.0, D_AFTER_STOP, 3.0], 12.0, 0)
    return Lens([front, back], [Air(), glass, Air()], [D_AFTER_STOP, 3.0], 12.0, 0)


def _bundle(z_start: float, direction) -> Rays:
    g = torch.Generator().manual_seed(0)
    xy = (torch.rand(400, 2, generator=g, dtype=torch.float64) * 2 - 1) * 2.2
    o = torch.cat([xy, torch.full((400, 1), z_start, dtype=torch.float64)], -1)
    d = torch.tensor(direction, dtype=torch.float64).expand(400, 3)
    return Rays(o, d, torch.full((400,), 587.56, dtype=torch.float64))


def _crossing_inside(o, d):
    """Closed form: the line ``o + t d`` meets ``z = 0`` at ``t = -o_z / d_z``; inside the stop?"""
    t = -o[:, 2] / d[:, 2]
    x, y = o[:, 0] + t * d[:, 0], o[:, 1] + t * d[:, 1]
    return x * x + y * y <= R_STOP ** 2


@pytest.mark.parametrize("direction", [(0.0, 0.0, 1.0), (0.0, 0.12, 1.0), (0.08, -0.1, 1.0)])
def test_forward_clip_at_the_line_crossing_and_no_move(direction):
    rays = _bundle(-5.0, direction)
    out = _singlet(True).trace(rays)
    ref = _singlet(False).trace(rays)
    expect = ref.valid & _crossing_inside(rays.o, rays.d)
    assert 50 < int(expect.sum()) < 350   # both outcomes occur
    assert torch.equal(out.valid, expect)
    ok = out.valid
    torch.testing.assert_close(out.o[ok], ref.o[ok], rtol=0, atol=1e-12)
    torch.testing.assert_close(out.d[ok], ref.d[ok], rtol=0, atol=1e-12)
    torch.testing.assert_close(out.opl[ok], ref.opl[ok], rtol=0, atol=1e-12)


@pytest.mark.parametrize("direction", [(0.0, 0.0, -1.0), (0.0, 0.1, -1.0)])
def test_reverse_crosses_the_stop_behind_the_ray(direction):
    """Traced backwards the rays leave the front surface (z ~ -0.3) towards -z: the stop plane
    z = 0 lies *behind* most of them (t < 0; ahead of those leaving the rim, which reaches
    z = +0.016), and its crossing still decides."""
    rays = _bundle(10.0, direction)
    out = _singlet(True).trace(rays, reverse=True)
    ref = _singlet(False).trace(rays, reverse=True)
    z_end = ref.o[ref.valid][:, 2]
    assert int((z_end < 0).sum()) > 100 and bool((z_end > -0.31).all())   # mostly t < 0
    expect = ref.valid & _crossing_inside(ref.o, ref.d)
    assert 50 < int(expect.sum()) < 350
    assert torch.equal(out.valid, expect)
    torch.testing.assert_close(out.o[expect], ref.o[expect], rtol=0, atol=1e-12)
    torch.testing.assert_close(out.opl[expect], ref.opl[expect], rtol=0, atol=1e-12)


def test_compiled_run_clips_like_eager(uncompiled):
    """The fused kernels' stop step (their logic, without the compiler) agrees with eager."""
    lens = _singlet(True)
    rays = _bundle(-5.0, (0.0, 0.1, 1.0))
    eager = lens.trace_to_sensor(rays)
    fused = lens.trace_to_sensor(rays, options=TraceOptions(compile=True))
    assert torch.equal(eager.valid, fused.valid)
    torch.testing.assert_close(fused.o[fused.valid], eager.o[eager.valid], rtol=0, atol=1e-12)


def test_recorded_stop_hit_lies_on_the_plane():
    rays = _bundle(-5.0, (0.0, 0.1, 1.0))
    out, hits = _singlet(True).trace(rays, record=True)
    ok = out.valid
    assert float(hits[0][ok][:, 2].abs().max()) < 1e-12
    torch.testing.assert_close(hits[0][ok][:, 1], rays.o[ok][:, 1] + 5.0 * 0.1, rtol=0,
                               atol=1e-12)


def test_real_surfaces_out_of_order_still_refused():
    """A stop may lie in a sag, but the lens surfaces around it keep their order."""
    with pytest.raises(ValueError, match="across the stop"):
        Lens([Asphere(0.0, 2.0), Aperture(1.0), Asphere(0.0, 2.0)], [Air()] * 4,
             [0.0, 0.5, -1.0], 5.0, 1)


ZMX = """VERS 190513 80 123457 L123457
MODE SEQ
NAME VSTOP
UNIT MM X W X CM MR CPMM
ENPD 4
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
FWGN 1
WAVM 1 0.5875618 1
PWAV 1
SURF 0
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ INFINITY
SURF 1
  TYPE STANDARD
  CURV 0.08333333333333333 0 0 0 0 ""
  DISZ 2.5
  GLAS ___BLANK 1 0 1.5168 64.17 0 0 0 0 0 0
  DIAM 4 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV -0.03333333333333333 0 0 0 0 ""
  DISZ 2.0
  DIAM 4 1 0 0 1 ""
SURF 3
  STOP
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ -0.3
  DIAM 2 1 0 0 1 ""
SURF 4
  TYPE STANDARD
  CURV 0.06666666666666667 0 0 0 0 ""
  DISZ 2.5
  GLAS ___BLANK 1 0 1.5168 64.17 0 0 0 0 0 0
  DIAM 4 1 0 0 1 ""
SURF 5
  TYPE STANDARD
  CURV -0.06666666666666667 0 0 0 0 ""
  DISZ 6.0
  DIAM 4 1 0 0 1 ""
SURF 6
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ 0
"""


def test_zmx_stop_in_sag_matches_optiland(tmp_path):
    """``DISZ -0.3`` on the STOP (between two singlets): the entrance pupil is the stop's image
    through the first lens, so the paraxial trace crosses the negative gap."""
    pytest.importorskip("optiland")
    from optiland.analysis import SpotDiagram
    from optiland.fileio import load_zemax_file
    from optiland.materials import IdealMaterial

    path = tmp_path / "vstop.zmx"
    path.write_text(ZMX)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens = read_zmx(path)
        optic = load_zemax_file(str(path))
    assert isinstance(lens.stop, Aperture) and float(lens.distances[lens.stop_index + 1]) < 0
    n = float(lens.materials[1].n(587.5618))
    for i, m in enumerate([1.0, n, 1.0, 1.0, n, 1.0, 1.0]):   # the same indices in both
        optic.surface_group.surfaces[i].material_post = IdealMaterial(n=m)
    p = paraxial(lens)
    assert float(p.efl) == pytest.approx(float(optic.paraxial.f2()), rel=1e-9)
    assert float(p.entrance_pupil_diameter) == pytest.approx(float(optic.paraxial.EPD()),
                                                            rel=1e-9)
    ep = float(p.entrance_pupil_z) - float(lens.z_vertices()[0])   # from SURF 1
    assert ep == pytest.approx(float(optic.paraxial.EPL()), rel=1e-9, abs=1e-9)
    assert ep > 0.5   # behind the first lens: the image of the stop, not SURF 1
    # real rays: the on-axis spot (rays at the paraxial entrance pupil, filling the stop)
    with torch.no_grad():
        dl = float(spot_diagram(lens, 0.0, 587.5618, "hexapolar:12",
                                pupil="paraxial").rms_radius)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sd = SpotDiagram(optic, fields=[(0.0, 0.0)], wavelengths=[0.5875618], num_rings=12,
                         reference="centroid")
    ol = float(sd.rms_spot_radius()[0][0])
    assert dl == pytest.approx(ol, rel=5e-3)
    assert not math.isnan(dl)


def test_start_plane_before_a_lens_reaching_through_a_leading_stop():
    """Sampled rays start before the first *lens* surface, 2 mm before the stop plane here."""
    from deeplens.optics.sampling import field_rays, start_plane_z

    glass = ModelGlass(1.5168, 64.17)
    lens = Lens([Aperture(R_STOP), Asphere(0.1, 2.5), Asphere(-0.05, 2.5)],
                [Air(), Air(), glass, Air()], [0.0, -2.0, 3.0], 12.0, 0)
    assert start_plane_z(lens) <= -3.0
    pupil = torch.tensor([[0.0, 0.0], [0.0, 1.0], [0.0, 1.6]], dtype=torch.float64)
    rays = field_rays(lens, 0.0, 587.56, pupil, 0.0)
    out = lens.trace(rays)
    assert out.valid.tolist() == [True, True, False]   # 1.6 mm > R_STOP at the stop plane
