"""Parameter pick-ups (``PPAR``) re-evaluated in a configuration other than the saved one.

OpticStudio saves the active configuration's solved parameters only; in another configuration
a pick-up is solved again from that configuration's values.  A fold written as ``break (tilt
t), mirror, break (picking up t)`` whose configuration 2 turns the fold the other way (``PRAM``
of the first break only, as OpticStudio's "Mach Zender Interferometer" sample does) must get
the return break's tilt from its pick-up: kept at the saved value, the frame after the fold
would be turned 90 degrees away from the beam, and every ray missed the mirror after it.

tests/data/zmx_opticstudio/fold_pickup_2conf.zmx: a 45-degree flat fold, then a concave mirror
(``CURV 0.02``, R = 50 mm) 20 mm on, the image 25 mm after it: closed forms ``EFL = R/2 = 25``
and, for a ray parallel to the axis at height ``h``, the transverse spherical aberration of a
spherical mirror at its paraxial focus, ``h**3 / (2 R**2)`` to third order.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import pytest
import torch

from deeplens.optics.io import ZemaxFileError, ZemaxWarning, lens_to_dict, read_zmx
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from zmx_mconf_apply import single_configuration

FOLD = Path(__file__).resolve().parents[2] / "data" / "zmx_opticstudio" / "fold_pickup_2conf.zmx"
R = 50.0


def _read(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        return read_zmx(path, **kw).to(torch.float64)


@pytest.mark.parametrize("config", [1, 2])
def test_fold_turned_the_other_way_focuses_as_the_closed_form(config):
    lens = _read(FOLD, config=config)
    assert float(paraxial(lens).efl) == pytest.approx(R / 2, rel=1e-9)
    h = 0.5
    o = torch.tensor([[0.0, 0.0, -1.0], [0.0, h, -1.0], [h, 0.0, -1.0]], dtype=torch.float64)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(3, 3)
    out = lens.trace_to_sensor(Rays(o, d, torch.full((3,), 550.0, dtype=torch.float64)))
    assert out.valid.all()
    # third-order transverse aberration h^3/(2R^2) = 2.5e-5 mm; the fifth order is ~(h/R)^2
    # smaller, far below the 1e-7 mm allowed
    lateral = out.o[1:, :2].norm(dim=-1)
    assert torch.allclose(lateral, torch.full_like(lateral, h ** 3 / (2 * R ** 2)), atol=1e-7)
    assert out.o[0, :2].abs().max() < 1e-12


def test_a_solve_deeplens_does_not_evaluate_is_noted_in_another_configuration(tmp_path):
    text = FOLD.read_text().replace("  PARM 2 0\n  PARM 3 45\n  PPAR 3 2",
                                    "  PARM 2 0\n  PPAR 2 -1 1 0\n  PARM 3 45\n  PPAR 3 2", 1)
    p = tmp_path / "fold.zmx"
    p.write_text(text)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        read_zmx(p, config=2)
    notes = [str(x.message) for x in w if "PPAR" in str(x.message)]
    assert len(notes) == 1 and "SURF 4" in notes[0] and "parameter 2" in notes[0]
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        read_zmx(p, config=1)          # the saved configuration: its values are the solved ones
    assert not [x for x in w if "PPAR" in str(x.message)]


def test_the_test_only_applier_solves_the_pick_up_as_well(tmp_path):
    """tests/optics/io/zmx_mconf_apply.py (the corpus oracles' one-configuration files, no code
    shared with deeplens) writes the return break's tilt solved: -45 in configuration 2."""
    for k in (1, 2):
        alone = tmp_path / f"c{k}.zmx"
        alone.write_text(single_configuration(FOLD, k))
        assert lens_to_dict(_read(FOLD, config=k)) == lens_to_dict(_read(alone))
    assert "PARM 3 -45.0" in (tmp_path / "c2.zmx").read_text()


# Two plano-convex N-BK7 lenses (c = 0.05 per mm, thickness t), the second turned round: its
# flat face picks up the first lens' material (GLAS ... 2 1) and thickness (PZUP 1 1 0 0), as
# the return pass of OpticStudio's "Twyman Green Interferometer" sample picks up its test lens.
# Configuration 2 thickens the first lens to 6 mm; configuration 3 empties it (air, flat).
_PICKED = """VERS 130724 324 23203
MODE SEQ
NAME material and thickness pick-ups
UNIT MM X W X CM MR CPMM
ENPD 4
GCAT SCHOTT
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
WAVM 1 0.55 1
PWAV 1
SURF 0
  TYPE STANDARD
  CURV 0.0
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV 0.05
  DISZ 4
  GLAS N-BK7 0 0 1.5 40 0 0 0 0 0 0
  DIAM 5 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV 0.0
  DISZ 10
  DIAM 5 1 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV 0.0
  DISZ 4
  GLAS N-BK7 2 1 1.5 40 0 0 0 0 0 0
  PZUP 1.0 1 0 0
  DIAM 5 1 0 0 1 ""
SURF 4
  TYPE STANDARD
  CURV -0.05
  DISZ 30
  DIAM 5 1 0 0 1 ""
SURF 5
  TYPE STANDARD
  CURV 0.0
  DISZ 0
MNUM 3 1
THIC   1   1 4.0E+0 0 0 0 1 1 1 0 0
THIC   1   2 6.0E+0 0 0 0 2 1 1 0 0
THIC   1   3 4.0E+0 0 0 0 3 1 1 0 0
GLSS   1   1 "N-BK7" 0 0 0 1 2 0 0.0 ""
GLSS   1   2 "N-BK7" 0 0 0 2 2 0 0.0 ""
GLSS   1   3 "" 0 0 0 3 2 0 0.0 ""
CRVT   1   1 5.0E-2 0 0 0 1 3 1 0 0
CRVT   1   2 5.0E-2 0 0 0 2 3 1 0 0
CRVT   1   3 0.0E+0 0 0 0 3 3 1 0 0
"""


def _n_bk7(um: float) -> float:
    """N-BK7's index (SCHOTT's Sellmeier coefficients) at ``um`` micrometres."""
    lam2 = um * um
    b, c = (1.03961212, 0.231792344, 1.01046945), (0.00600069867, 0.0200179144, 103.560653)
    return math.sqrt(1 + sum(bi * lam2 / (lam2 - ci) for bi, ci in zip(b, c)))


@pytest.mark.parametrize("config, t", [(1, 4.0), (2, 6.0)])
def test_material_and_thickness_pick_ups_follow_the_configuration(tmp_path, config, t):
    """Two thin surfaces of power (n - 1) c a reduced distance t/n + 10 + t/n apart (the flat
    faces add none): EFL = 1 / (2 phi - d phi**2); with the second lens' thickness kept at the
    saved 4 mm, configuration 2's EFL was 24.5675 mm (2 % short)."""
    path = tmp_path / "picked.zmx"
    path.write_text(_PICKED)
    n = _n_bk7(0.55)
    phi, d = (n - 1) * 0.05, 2 * t / n + 10.0
    want = 1.0 / (2 * phi - d * phi ** 2)
    for lens in (_read(path, config=config), _read(_alone(tmp_path, path, config))):
        assert float(paraxial(lens).efl) == pytest.approx(want, rel=1e-9)


def test_a_material_picked_up_from_air_is_air(tmp_path):
    """Configuration 3 empties the first lens (GLSS 1 "", CRVT 1 0): the second lens' flat face
    picks up air, so no surface has glass (kept as saved, the second lens stayed N-BK7)."""
    path = tmp_path / "picked.zmx"
    path.write_text(_PICKED)
    for lens in (_read(path, config=3), _read(_alone(tmp_path, path, 3))):
        media = [s["material"] for s in lens_to_dict(lens)["surfaces"] if "material" in s]
        assert media and all(m == "AIR" for m in media)


def _alone(tmp_path, path, k):
    """The test-only applier's one-configuration file of configuration ``k``."""
    alone = tmp_path / f"alone{k}.zmx"
    alone.write_text(single_configuration(path, k))
    return alone


@pytest.mark.parametrize("record, cut", [("  PPAR 3 2 1.0 0.0 0", "  PPAR 3 2"),
                                         ("  PPAR 3 2 1.0 0.0 0", "  PPAR 3 2 1.0")])
def test_a_truncated_pick_up_is_refused_on_its_line(tmp_path, record, cut):
    """A pick-up record without its scale or offset is refused at its line, naming the field
    (the reader needs both to solve it again in another configuration)."""
    text = FOLD.read_text()
    assert record in text
    p = tmp_path / "cut.zmx"
    p.write_text(text.replace(record, cut, 1))
    line = text.splitlines().index(record) + 1
    what = "scale" if cut.count(" ") == 4 else "offset"
    with pytest.raises(ZemaxFileError, match=rf"cut\.zmx:{line}: .*pick-up {what}") as e:
        read_zmx(p, config=2)
    assert e.value.line == line


def test_a_truncated_thickness_pick_up_is_refused_on_its_line(tmp_path):
    text = _PICKED.replace("  PZUP 1.0 1 0 0", "  PZUP 1.0", 1)
    p = tmp_path / "cut.zmx"
    p.write_text(text)
    line = text.splitlines().index("  PZUP 1.0") + 1
    with pytest.raises(ZemaxFileError, match=rf"cut\.zmx:{line}: .*pick-up scale"):
        read_zmx(p)

