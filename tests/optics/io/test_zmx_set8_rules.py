"""Readings met by the eighth unseen set of real files (docs/guide/zemax.md, "An eighth unseen
set"), each on a synthetic file checked by a closed form:

* a material *pickup* (``GLAS NAME 2 k ...``, OpticStudio's Pickup material solve, code 2) takes
  SURF ``k``'s material, air included: the name and ``n_d V_d`` written on the line are a copy
  OpticStudio keeps (``___BLANK ... 1.5 40`` where ``k`` is air), not the material.  The reader
  had taken ``___BLANK`` with solve code 2 for a model glass of the written numbers: in
  OpticStudio's short-course file ``double-pass_all misalignments`` three air gaps became
  glass of n_d 1.5 (EFL 74.52 mm against 4.6e6 mm, the near-afocal double pass).
"""

from __future__ import annotations

import math

import pytest
from test_zmx import write
from test_zmx_prisms import _surf

from deeplens.optics.io import ZemaxFileError, read_zmx
from deeplens.optics.paraxial import paraxial

_HEAD = """VERS 170912 299 123456
MODE SEQ
NAME set8
UNIT MM X W X CM MR CPMM
ENPD 10.0
FTYP 0 0 1 1 0 0 0
YFLN 0
WAVM 1 0.5875618 1
PWAV 1
"""

#: a model-glass singlet: radii (mm), centre thickness (mm), then a dummy plane D behind it and
#: the image plane a further L behind that; the slab between the dummy plane and the image is
#: where the pickup's material goes
R1, R2, T, D, L, ND = 50.0, -80.0, 5.0, 10.0, 60.0, 1.6


def _file(dummy_glas, lens_glas=f"___BLANK 1 0 {ND} 50.0 0 0 0 0 0 0"):
    blocks = [_surf(disz="INFINITY"), _surf(disz=5.0, stop=True, diam=5.0),
              _surf(curv=1 / R1, disz=T, glas=lens_glas, diam=8.0),
              _surf(curv=1 / R2, disz=D, diam=8.0),
              _surf(disz=L, glas=dummy_glas), _surf()]
    lines = []
    for k, b in enumerate(blocks):
        lines += [f"SURF {k}"] + b
    return _HEAD + "\n".join(lines) + "\n"


def _focus_behind_dummy(n_lens, n_slab):
    """Distance from the dummy plane to the paraxial focus, written out: the thick lens's back
    focal distance ``f (1 - (n - 1) T / (n R1))`` with ``1/f = (n - 1)(1/R1 - 1/R2 + (n - 1) T /
    (n R1 R2))``, less ``D``, times ``n_slab`` (a plane into index ``n_slab`` stretches the
    remaining path by it)."""
    n = n_lens
    phi = (n - 1) * (1 / R1 - 1 / R2 + (n - 1) * T / (n * R1 * R2))
    bfd = (1 - (n - 1) * T / (n * R1)) / phi
    return (bfd - D) * n_slab, 1 / phi


def _behind_dummy(lens, px):
    """The paraxial focus's distance behind the dummy plane, ``D`` behind the lens's rear face
    (the surface of curvature ``1/R2``), whether or not the reader keeps the plane."""
    rear = next(i for i, s in enumerate(lens.surfaces)
                if abs(float(getattr(s, "c", 0.0)) - 1 / R2) < 1e-12)
    return float(px.image_z) - float(lens.z_vertices()[rear]) - D


def _index(m, wl):
    return float(m.n(wl))


def test_pickup_from_air_is_air(tmp_path):
    """``GLAS ___BLANK 2 3 1.5 40``: SURF 3 (the lens's rear face) is followed by air, so the
    gap after the dummy plane is air: the focus lies ``bfd - D`` behind it (1.5 times that if
    the written 1.5 were the material), the EFL that of the singlet alone."""
    lens = read_zmx(write(tmp_path, _file("___BLANK 2 3 1.5 40.0 0 0 0 0 0 0"))).double()
    wl = float(lens.spec.primary_wavelength_nm)
    n_lens = _index(lens.materials[2], wl)
    assert n_lens == pytest.approx(ND, abs=1e-12)   # a model glass at d: its n_d
    assert all(_index(m, wl) == 1.0 for m in lens.materials[3:]), [str(m) for m in
                                                                   lens.materials]
    behind, efl = _focus_behind_dummy(n_lens, 1.0)
    px = paraxial(lens)
    assert float(px.efl) == pytest.approx(efl, rel=1e-12)
    assert _behind_dummy(lens, px) == pytest.approx(behind, rel=1e-10)
    wrong, _ = _focus_behind_dummy(n_lens, 1.5)
    assert abs(_behind_dummy(lens, px) - wrong) > 10.0


def test_pickup_from_a_glass_takes_its_material(tmp_path):
    """``GLAS ___BLANK 2 2 1.5 40`` (written numbers not the source's): the slab behind the
    dummy plane is SURF 2's model glass (n_d 1.6), and the focus lies ``(bfd - D) n`` behind the
    plane (the plane refracts into it)."""
    lens = read_zmx(write(tmp_path, _file("___BLANK 2 2 1.5 40.0 0 0 0 0 0 0"))).double()
    wl = float(lens.spec.primary_wavelength_nm)
    n_slab = _index(lens.materials[-1], wl)
    assert n_slab == pytest.approx(ND, abs=1e-12)
    behind, efl = _focus_behind_dummy(ND, n_slab)
    px = paraxial(lens)
    # the EFL in image space of index n': |n'|/φ (deeplens' image-side focal length)
    assert float(px.efl) == pytest.approx(efl * n_slab, rel=1e-10)
    assert _behind_dummy(lens, px) == pytest.approx(behind, rel=1e-10)


def test_pickup_of_a_catalogue_glass_by_another_name(tmp_path):
    """A pickup whose written name is stale takes the source's glass: SURF 2 is N-BK7, the line
    names F2; the slab is N-BK7 (SCHOTT's n_d 1.5168)."""
    text = _file("F2 2 2 1.62 36.4 0 0 0 0 0 0", lens_glas="N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0")
    lens = read_zmx(write(tmp_path, "GCAT SCHOTT\n" + text)).double()
    assert "N-BK7" in str(lens.materials[-1]), [str(m) for m in lens.materials]
    wl = float(lens.spec.primary_wavelength_nm)
    assert _index(lens.materials[-1], wl) == pytest.approx(1.5168, abs=1e-4)
    assert not math.isclose(_index(lens.materials[-1], wl), 1.62, abs_tol=1e-2)


@pytest.mark.parametrize("glas, why", [("___BLANK 2 5 1.5 40.0 0 0 0 0 0 0", "earlier surface"),
                                        ("___BLANK 2", "without the surface")])
def test_pickup_from_a_later_surface_or_none_is_refused(tmp_path, glas, why):
    """Pickups read prior surfaces only (OpticStudio User Guide, *Restrictions*): a pickup from
    itself or a later surface, or one without a surface number, is a located error."""
    p = write(tmp_path, _file(glas))
    with pytest.raises(ZemaxFileError, match=why) as e:
        read_zmx(p)
    assert "t.zmx:" in str(e.value)
