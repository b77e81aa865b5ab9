"""CODE V ``.seq`` defaults and the commands real files use (docs/guide/codev.md, "Defaults"):
no ``STO``, several ``WL`` without ``REF``, no ``SI``, no ``RDM``, private glass catalogues
(``PRV``), obscurations and holes (``CIR OBS``, ``CIR HOL``), pickups (``PIK``) and ``AC 0``;
each checked by a closed form or against the same lens written out in full."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.optics.errors import LensFileError
from deeplens.optics.io.codev import CodeVWarning, read_seq
from deeplens.optics.io.codev_private import PrivateGlass
from deeplens.optics.io.lensfile import lens_to_dict
from deeplens.optics.paraxial import paraxial

HEAD = "RDM Y\nTIT 'x'\nDIM M\nWL 587.5618\nEPD 10\nYAN 0 5\nSO 0 1e10\n"
BODY = "S 50 5 NBK7_SCHOTT\n  STO\nS -50 45\nSI 0 0\n"


def _seq(tmp_path, text, name="t.seq"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _thick_lens_efl(n, r1, r2, t):
    """Lensmaker's equation of a thick singlet in air."""
    return 1.0 / ((n - 1.0) * (1.0 / r1 - 1.0 / r2 + (n - 1.0) * t / (n * r1 * r2)))


def test_no_sto_puts_the_stop_on_surface_1(tmp_path):
    """No STO: the stop is the first surface (rayoptics' and optiland's readers), with a located
    warning; the lens is the one with STO on surface 1, whose entrance pupil lies at that
    surface's vertex (the stop is in object space: position 0)."""
    with pytest.warns(CodeVWarning, match=r"t\.seq:8: no STO line: the stop is the first"):
        a = read_seq(_seq(tmp_path, HEAD + BODY.replace("  STO\n", "")))
    b = read_seq(_seq(tmp_path, HEAD + BODY, "b.seq"))
    assert a.stop_index == 0
    assert lens_to_dict(a) == lens_to_dict(b)
    assert float(paraxial(a).entrance_pupil_position) == 0.0


def test_several_wl_without_ref_take_the_first(tmp_path):
    """Several WL and no REF: the first wavelength is the reference (REF 1), with a warning."""
    head = HEAD.replace("WL 587.5618", "WL 486.1327 587.5618 656.2725")
    with pytest.warns(CodeVWarning, match=r"t\.seq:4: several wavelengths and no REF.*486\.1327"):
        a = read_seq(_seq(tmp_path, head + BODY))
    b = read_seq(_seq(tmp_path, head + "REF 1\n" + BODY, "b.seq"))
    assert a.spec.primary_wavelength_nm == 486.1327
    assert lens_to_dict(a) == lens_to_dict(b)


def test_no_si_is_an_image_at_the_last_thickness(tmp_path):
    """No SI: CODE V's image surface is always there; the image plane is at the last surface's
    thickness, as with ``SI 0 0``."""
    with pytest.warns(CodeVWarning, match=r"t\.seq:10: no SI line"):
        a = read_seq(_seq(tmp_path, HEAD + BODY.replace("SI 0 0\n", "")))
    b = read_seq(_seq(tmp_path, HEAD + BODY, "b.seq"))
    assert lens_to_dict(a) == lens_to_dict(b)
    assert float(a.d_sensor) == 45.0


def test_no_rdm_reads_radii_unless_told(tmp_path):
    """No RDM line: radii (with a warning naming the flag); radius_mode=False: curvatures."""
    text = HEAD.replace("RDM Y\n", "") + BODY.replace("S 50", "S 0.02").replace("S -50",
                                                                                  "S -0.02")
    p = _seq(tmp_path, text.replace("EPD 10", "EPD 0.01"))
    with pytest.warns(CodeVWarning, match="no RDM line.*radius_mode=False"):
        a = read_seq(p)
    assert float(a.surfaces[0].c) == 1 / 0.02
    b = read_seq(_seq(tmp_path, text, "b.seq"), radius_mode=False)
    assert float(b.surfaces[0].c) == 0.02


def _cauchy(w_nm):
    return 1.5 + 5000.0 / w_nm ** 2


PWL = [400.0, 450.0, 486.1327, 550.0, 587.5618, 656.2725, 750.0, 900.0]
PRV = ("PRV\n  PWL " + " ".join(repr(w) for w in PWL) + "\n  'MYGLASS' "
       + " ".join(repr(_cauchy(w)) for w in PWL) + "\nEND\n")


def test_private_glass_gives_its_table_and_the_thick_lens_efl(tmp_path):
    """A PRV glass: its own index at a listed wavelength (exactly), so the singlet's EFL is the
    lensmaker's with that index (float64: 1e-12 relative)."""
    lens = read_seq(_seq(tmp_path, HEAD + PRV + BODY.replace("NBK7_SCHOTT", "'MYGLASS'")))
    m = lens.materials[1]
    assert isinstance(m, PrivateGlass)
    w = torch.tensor(PWL, dtype=torch.float64)
    assert m.n(w).tolist() == [_cauchy(v) for v in PWL]
    n = _cauchy(587.5618)
    assert float(paraxial(lens).efl) == pytest.approx(_thick_lens_efl(n, 50.0, -50.0, 5.0),
                                                      rel=1e-12)


def test_private_glass_interpolates_as_a_not_a_knot_spline():
    """Between its wavelengths: scipy's not-a-knot cubic spline through the table (rayoptics'
    interpolation), to float64 round-off; and the index is differentiable in the wavelength."""
    interpolate = pytest.importorskip("scipy.interpolate")
    g = PrivateGlass("G", PWL[::-1], [_cauchy(v) for v in PWL[::-1]])
    ref = interpolate.CubicSpline(PWL, [_cauchy(v) for v in PWL], bc_type="not-a-knot")
    q = torch.linspace(400.0, 900.0, 301, dtype=torch.float64)
    assert g.n(q).tolist() == pytest.approx(ref(q.numpy()).tolist(), rel=0, abs=1e-14)
    w = torch.tensor([520.0], dtype=torch.float64, requires_grad=True)
    (dn,) = torch.autograd.grad(g.n(w).sum(), w)
    assert float(dn) == pytest.approx(float(ref(520.0, 1)), rel=1e-12)


def test_private_glass_must_span_the_lens_wavelengths(tmp_path):
    head = HEAD.replace("WL 587.5618", "WL 587.5618 1000; REF 1")
    p = _seq(tmp_path, head + PRV + BODY.replace("NBK7_SCHOTT", "'MYGLASS'"))
    with pytest.raises(LensFileError, match=r"'MYGLASS' is tabulated at 400\.0 - 900\.0 nm.*"
                                            r"\[1000\.0\]") as e:
        read_seq(p)
    assert e.value.line == 12


def test_cir_obs_is_a_central_obscuration_in_file_units(tmp_path):
    """CIR OBS r on a surface: its obscuration, r in the file's unit (DIM I: 25.4 mm)."""
    text = (HEAD.replace("DIM M", "DIM I").replace("EPD 10", "EPD 0.4")
            + "S 2 0.2 NBK7_SCHOTT\n  STO\n  CIR OBS L'A' 0.05\nS -2 1.8\nSI 0 0\n")
    lens = read_seq(_seq(tmp_path, text))
    assert float(lens.surfaces[0].obscuration) == pytest.approx(0.05 * 25.4, rel=1e-15)


def test_cir_hol_is_read_as_an_obscuration_with_a_warning(tmp_path):
    with pytest.warns(CodeVWarning, match=r"t\.seq:11: CIR HOL 1\.0 mm"):
        lens = read_seq(_seq(tmp_path, HEAD + BODY.replace("S -50 45", "S -50 45\n  CIR HOL 1")))
    assert float(lens.surfaces[1].obscuration) == 1.0


def test_pickups_are_applied(tmp_path):
    """PIK RDY S2 RDY S1 -1 (a symmetric lens) and PIK THI S2 THI S1 2 1 (t2 = 2 t1 + 1)."""
    text = HEAD + "S 50 5 NBK7_SCHOTT\n  STO\nS 10 0\nSI 0 0\n" \
        "PIK RDY S2 Z1 RDY S1 Z1 -1\nPIK THI S2 THI S1 2.0 1.0\n"
    lens = read_seq(_seq(tmp_path, text))
    assert float(lens.surfaces[1].c) == -1 / 50
    assert float(lens.d_sensor) == 11.0
    with pytest.raises(LensFileError, match="PIK: zoom position Z2") as e:
        read_seq(_seq(tmp_path, text.replace("S2 Z1", "S2 Z2"), "z.seq"))
    assert e.value.line == 12


def test_ac_zero_is_read(tmp_path):
    a = read_seq(_seq(tmp_path, HEAD + BODY.replace("  STO\n", "  STO\n  AC 0\n")))
    b = read_seq(_seq(tmp_path, HEAD + BODY, "b.seq"))
    assert lens_to_dict(a) == lens_to_dict(b)
    assert math.isfinite(float(paraxial(a).efl))


def test_so_inf_is_an_object_at_infinity(tmp_path):
    """``SO 0 inf`` (as optiland's files write it) is the object at infinity, as ``SO 0 1e10``."""
    a = read_seq(_seq(tmp_path, HEAD.replace("SO 0 1e10", "SO 0 inf") + BODY))
    b = read_seq(_seq(tmp_path, HEAD + BODY, "b.seq"))
    assert math.isinf(a.spec.object_distance_mm)
    assert lens_to_dict(a) == lens_to_dict(b)


def test_a_bare_name_only_in_older_catalogues_names_them(tmp_path):
    """``bk7`` (rayoptics' test.seq) is only in the withdrawn SCHOTT entries and the previous
    SCHOTT and OHARA catalogues: the refusal says so and gives the spelling that loads, which
    does."""
    p = _seq(tmp_path, HEAD + BODY.replace("NBK7_SCHOTT", "bk7"))
    with pytest.raises(LensFileError, match=r"'bk7' is in no current catalogue, only in "
                                            r"SCHOTT \(withdrawn\), SCHOTT \(previous\).*e\.g\. BK7_SCHOTT") as e:
        read_seq(p)
    assert e.value.line == 8
    read_seq(_seq(tmp_path, HEAD + BODY.replace("NBK7_SCHOTT", "BK7_SCHOTT"), "b.seq"))


def _singlet_trace(n, y, u, s_img=None):
    """The paraxial ray (height y, slope u at the first vertex) through BODY's singlet (R 50,
    -50, 5 mm of index n, in air), by hand: ``(y, u)`` after the last vertex, or the height
    ``s_img`` beyond it."""
    u = (u - y * (n - 1.0) / 50.0) / n
    y = y + 5.0 * u
    u = n * u - y * (1.0 - n) / -50.0
    return (y, u) if s_img is None else y + s_img * u


def test_fno_with_a_finite_object_is_a_working_f_number(tmp_path):
    """FNO with a finite object (rayoptics' reading, with a warning): the axial marginal ray
    leaves at |u'| = 1 / (2 F), traced here by hand through the singlet (stop on its first
    vertex: the entrance pupil there)."""
    head = HEAD.replace("SO 0 1e10", "SO 0 200").replace("EPD 10", "FNO 4")
    with pytest.warns(CodeVWarning, match=r"t\.seq:5: FNO 4\.0 with the object at a finite"):
        lens = read_seq(_seq(tmp_path, head + BODY))
    n = float(lens.materials[1].n(587.5618))
    h = lens.spec.aperture_value / 2.0
    _, u = _singlet_trace(n, h, h / 200.0)
    assert abs(u) == pytest.approx(1.0 / 8.0, rel=1e-12)
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(2 * h, rel=1e-12)


def test_yim_with_a_finite_object_gives_those_paraxial_image_heights(tmp_path):
    """YIM with a finite object: the chief ray of each field angle (object height
    ``(s + l_EP) tan θ``, the pupil on the first vertex) reaches the paraxial image plane at the
    given height, traced here by hand."""
    head = HEAD.replace("SO 0 1e10", "SO 0 200").replace("YAN 0 5", "YIM 0 3")
    lens = read_seq(_seq(tmp_path, head + BODY))
    n = float(lens.materials[1].n(587.5618))
    y, u = _singlet_trace(n, 200.0, 1.0)     # the axial ray from the object point (slope 1)
    s_img = -y / u                            # the paraxial image plane behind the last vertex
    t = math.tan(math.radians(lens.spec.fields_deg[1]))
    y_img = _singlet_trace(n, 0.0, t, s_img)  # the chief ray through the first vertex's centre
    assert abs(y_img) == pytest.approx(3.0, rel=1e-12)
