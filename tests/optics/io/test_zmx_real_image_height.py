"""FTYP 3 (real image height): the chief-ray solve steps back from a trial angle that fails.

The hand-written singlet below (stop 2 mm in front, a rear surface concave towards the image,
``CURV 0.1``) totally reflects its chief ray beyond about 29 deg, while its paraxial slope
(0.596 mm/deg) puts the first trial for a 20 mm image height at 33.6 deg: the old solver got a
NaN there and refused the field; the real chief ray reaches 20 mm at 24.6 deg.
"""

from __future__ import annotations

import math
import re

import pytest
from test_zmx import singlet, write

from deeplens.optics.io import ZemaxFileError, read_zmx
from deeplens.optics.io.zmx_system import chief_height

TIR_SINGLET = dict(curv1=0.02, curv2=0.1, t=8, bfl=20, s1_extra=(), k=0, diam1=6)


def tir_singlet(h: float) -> str:
    return singlet(ftyp="FTYP 3 0 2 2 0 0 0", yfln=f"YFLN 0 {h!r}", **TIR_SINGLET)


@pytest.mark.parametrize("h", [20.0, 30.0])
def test_solve_steps_back_from_a_failing_first_trial(tmp_path, h):
    lens = read_zmx(write(tmp_path, tir_singlet(h)))
    theta = lens.spec.fields_deg[1]
    # the case the test is about: the paraxial first trial h / slope fails (TIR)
    slope = abs(chief_height(lens, 1e-3)) / 1e-3
    assert math.isnan(chief_height(lens, h / slope))
    assert 0.0 < theta < h / slope
    # the solved field's chief ray lands at the height (float64 trace: 1e-12 relative)
    assert abs(chief_height(lens, theta)) == pytest.approx(h, abs=1e-10 * h)
    # and it is the smallest such angle: heights grow monotonically on [0, theta]
    hs = [abs(chief_height(lens, theta * k / 8)) for k in range(1, 9)]
    assert all(b > a for a, b in zip(hs, hs[1:]))


def test_a_first_trial_that_works_needs_no_step_back(tmp_path):
    lens = read_zmx(write(tmp_path, tir_singlet(5.0)))
    theta = lens.spec.fields_deg[1]
    assert abs(chief_height(lens, theta)) == pytest.approx(5.0, abs=1e-10 * 5.0)


def test_an_unreachable_height_is_refused_with_the_last_chief_ray_found(tmp_path):
    """A singlet whose chief rays are totally reflected at its rear surface (R = -10 mm) from
    about 65.3 deg and miss its front surface from 65.4 deg (a hand trace), never landing above
    15 mm: the refusal names the last chief ray found, the failing angle and where it stops."""
    text = singlet(ftyp="FTYP 3 0 2 2 0 0 0", yfln="YFLN 0 500", curv1=0.05, curv2=-0.1, t=8,
                   bfl=20, s1_extra=(), k=0, diam1=6)
    with pytest.raises(ZemaxFileError, match=r"t\.zmx:7: FTYP 3 \(real image height\): no chief "
                                             r"ray reaches image height 500 mm .*the chief ray "
                                             r"of 6[45]\.[0-9]+ deg lands at [0-9.]+ mm; from "
                                             r"6[45]\.[0-9]+ deg on it (is totally reflected at "
                                             r"SURF 3|misses SURF 2) \(line [0-9]+\)\)$"):
        read_zmx(write(tmp_path, text))


# ------------------------------------------------------------ set 12: wide-angle camera lenses
def wide_singlet(h: float, plane: str = "", aim: bool = False) -> str:
    """A stop 2 mm before a flat-fronted glass block (n = 1.5, non-dispersive) whose rear face
    is concave towards the image (R = -5 mm, fixed DIAM 4.9), the image 5 mm behind; ``plane``:
    a flat plane in air 2 mm behind the rear face with a fixed ``DIAM`` of that value (no
    ``CLAP``: OpticStudio's floating aperture needs power, so it is read with an automatic
    semi-diameter); ``aim``: real ray aiming (``RAIM`` type 2), the chief ray aimed at the stop's
    centre (here also the entrance pupil's: the stop is the first surface)."""
    gap = "  DISZ 3" if plane else "  DISZ 5"
    extra = ["SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 2", f'  DIAM {plane} 1 0 0 1 ""'
             ] if plane else []
    n_img = 5 if plane else 4
    return "\n".join([
        "VERS 170912 299 123456", "MODE SEQ", "NAME wide-angle singlet", "UNIT MM X W X CM MR CPMM",
        "ENPD 1", *(["RAIM 0 2 1 1 0 0 0 0 0"] if aim else []), "FTYP 3 0 2 1 0 0 0", "XFLN 0 0", f"YFLN 0 {h!r}", "WAVM 1 0.55 1", "PWAV 1",
        "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
        "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 2", '  DIAM 0.5 1 0 0 1 ""',
        "SURF 2", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 6.3",
        "  GLAS ___BLANK 1 0 1.5 0 0 0 0 0 0 0", '  DIAM 8 1 0 0 1 ""',
        "SURF 3", "  TYPE STANDARD", "  CURV -0.2", gap, '  DIAM 4.9 1 0 0 1 ""', *extra,
        f"SURF {n_img}", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", '  DIAM 20 1 0 0 1 ""',
    ]) + "\n"


def hand_chief_ray(theta_deg: float):
    """The chief ray of ``wide_singlet`` at ``theta_deg`` traced by hand (y-z plane, float64):
    through the stop's centre (the stop is the first surface, so it is the entrance pupil
    too), refracted at the flat front (Snell), met with the rear sphere ``y² + (z − z_c)² = 25``
    on its hemisphere towards the vertex, refracted there (vector Snell), on to the image.
    Returns ``(y on the image, y where its line crosses the rear vertex plane, y on the rear
    face)``."""
    th = math.radians(theta_deg)
    y1 = 2.0 * math.tan(th)
    s = math.sin(th) / 1.5
    dy, dz = s, math.sqrt(1 - s * s)
    zv = 2.0 + 6.3
    zc = zv - 5.0
    b = y1 * dy + (2.0 - zc) * dz
    cc = y1 * y1 + (2.0 - zc) ** 2 - 25.0
    t = -b + math.sqrt(b * b - cc)             # the origin is inside the sphere: the exit
    yh, zh = y1 + t * dy, 2.0 + t * dz
    assert zh > zc                             # on the branch towards the vertex
    ny, nz = yh / 5.0, (zh - zc) / 5.0         # outward normal, along the ray (d . n > 0)
    ci = dy * ny + dz * nz
    eta = 1.5
    ct = math.sqrt(1 - eta * eta * (1 - ci * ci))
    ey, ez = eta * dy + (ct - eta * ci) * ny, eta * dz + (ct - eta * ci) * nz
    y_img = yh + ey * (zv + 5.0 - zh) / ez
    return y_img, y1 + dy / dz * 6.3, yh


def test_a_chief_ray_that_crosses_a_rear_vertex_plane_beyond_its_radius_is_solved(tmp_path):
    """Set 12's 28 mm camera lens (``ob_US002779239_Example01P``, 21.6 mm): beyond 34 deg its
    chief ray crossed a rear surface's vertex plane outside the sphere (|y| > |R|) and was
    marked invalid, so the field was refused; it meets the sphere there, as OpticStudio
    traces it.  The solved angle's chief ray, traced by hand, lands at the height."""
    lens = read_zmx(write(tmp_path, wide_singlet(5.6)))
    theta = lens.spec.fields_deg[1]
    y_img, y_vertex_plane, y_rear = hand_chief_ray(theta)
    assert y_vertex_plane > 5.0 > 4.9 > y_rear     # the case: beyond |R| there, inside DIAM
    assert y_img == pytest.approx(5.6, abs=1e-9)
    assert chief_height(lens, theta) == pytest.approx(5.6, abs=1e-10)


def test_an_automatic_semi_diameter_does_not_stop_the_chief_ray(tmp_path):
    """Set 12's 35 mm and 28 mm Nikon lenses (ray aiming on): a flat plane in air with a fixed
    DIAM (read as automatic) still had its provisional 1e-3 mm semi-diameter while the real
    image height was solved, and the aimed chief ray, traced with the lens's clear apertures,
    stopped there beyond a few hundredths of a degree.  With the plane (DIAM 0.3) the field is
    the one of the same lens without it, bit for bit, and the plane's semi-diameter is then
    sized to pass that field's beam."""
    with_plane = read_zmx(write(tmp_path, wide_singlet(4.0, plane="0.3", aim=True), "p.zmx"))
    without = read_zmx(write(tmp_path, wide_singlet(4.0, aim=True), "q.zmx"))
    assert with_plane.ray_aiming
    assert with_plane.spec.fields_deg == without.spec.fields_deg
    theta = with_plane.spec.fields_deg[1]
    assert hand_chief_ray(theta)[0] == pytest.approx(4.0, abs=1e-9)
    plane = with_plane.surfaces[-1]
    assert float(plane.semi_diameter) > 3.0   # sized from the beam (was 1e-3 mm while solving)


def _refused_angle(tmp_path, text):
    """The smallest failing angle (deg) and the rest of an FTYP 3 refusal's message."""
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(write(tmp_path, text))
    m = re.search(r"from ([0-9.]+) deg on it (.*)$", str(e.value))
    assert m, str(e.value)
    return float(m.group(1)), m.group(2)


def test_the_refusal_names_the_surface_that_totally_reflects_the_chief_ray(tmp_path):
    """The wide-angle singlet never images 7 mm (its chief-ray heights peak near 5.7 mm at
    50 deg): from the failing angle on, the hand trace finds no refracted ray at the rear face
    (Snell's law has no solution), just below it one."""
    theta, why = _refused_angle(tmp_path, wide_singlet(7.0))
    assert why == "is totally reflected at SURF 3 (line 27))"
    with pytest.raises(ValueError):     # math.sqrt of a negative: no refracted ray
        hand_chief_ray(theta + 1e-3)   # (the message prints 6 digits: 5e-5 deg here)
    hand_chief_ray(theta - 1e-3)


def test_the_refusal_names_the_clear_aperture_that_stops_an_aimed_chief_ray(tmp_path):
    """With ray aiming the chief ray is traced with the lens's clear apertures (a fixed DIAM on
    a surface with power is OpticStudio's floating aperture): the rear face's DIAM 3 stops the
    chief ray of 4.5 mm; by hand, it meets the rear face beyond 3 mm from the failing angle on."""
    text = wide_singlet(4.5, aim=True).replace("DIAM 4.9 1", "DIAM 3 1")
    theta, why = _refused_angle(tmp_path, text)
    assert why == "falls outside the clear aperture of SURF 3 (line 28))"
    assert hand_chief_ray(theta + 1e-3)[2] > 3.0 > hand_chief_ray(theta - 1e-3)[2]
