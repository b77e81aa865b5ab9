"""A ``QED_TYPE`` Qbfs surface on a conic base (``CONI`` != 0), which no OpticStudio page
defines: read with Forbes' conic generalisation (the departure times ``sqrt((1 − k c² r²) / (1 −
(1+k) c² r²))``, Opt. Express 19, 9923 (2011), as optiland) and one located warning naming the
reading and the option that flips it (``qbfs_conic="refuse"``, ``--qbfs-conic refuse``).

The sag is checked against the closed form written here (Forbes 2007's Q0, Q1, Q2); the choice
is checked against the one real file of the case, Thorlabs' ASL5040-UV (k = −0.676): traced on
axis at its design wavelength by an independent meridional trace written here (its Q
polynomials built by Gram–Schmidt with Gauss–Chebyshev quadrature, not deeplens' rational
construction), its spot under Forbes' reading is diffraction limited and under the two other
readings (no factor; the sphere's factor ``1/sqrt(1 − c² r²)``) more than 100 times larger:
the file's own design decides the reading.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from deeplens.optics.errors import ZemaxWarning
from deeplens.optics.io import load_lens
from deeplens.optics.io.zmx import ZemaxFileError, read_zmx
from deeplens.optics.surfaces import QType

F64 = torch.float64
REAL = Path(__file__).resolve().parents[2] / "data" / "zmx_real" / "thorlabs_ASL5040-UV.zmx"

C, K, RN, A = 1 / 30.0, -0.5, 6.5, (0.05, -0.02, 0.01)

_SYNTH = f"""VERS 240000 3 0
MODE SEQ
UNIT MM X W X CM MR CPMM
ENPD 8
FTYP 0 0 1 1 0 0 0
WAVM 1 0.5875618 1
PWAV 1
YFLN 0
SURF 0
  TYPE STANDARD
  CURV 0
  DISZ INFINITY
SURF 1
  STOP
  TYPE QED_TYPE
  CURV {C!r}
  XDAT 1 0 0 0 1 0 0 ""
  XDAT 2 3 0 0 1 0 0 ""
  XDAT 3 {RN!r} 0 0 1 0 0 ""
  XDAT 4 {A[0]!r} 0 0 1 0 0 ""
  XDAT 5 {A[1]!r} 0 0 1 0 0 ""
  XDAT 6 {A[2]!r} 0 0 1 0 0 ""
  CONI {K!r}
  DISZ 4
  GLAS ___BLANK 1 0 1.6 0 0 0 0 0 0 0
  DIAM 6 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV 0
  DISZ 45
  DIAM 6 1 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV 0
  DISZ 0
"""


@pytest.fixture
def synth(tmp_path):
    p = tmp_path / "qbfs_conic.zmx"
    p.write_text(_SYNTH)
    return p


def _type_line(path):
    return next(i for i, ln in enumerate(Path(path).read_text().splitlines(), 1)
                if ln.split() == ["TYPE", "QED_TYPE"])


def _qbfs_warnings(rec):
    return [w.message for w in rec if isinstance(w.message, ZemaxWarning)
            and "Qbfs" in str(w.message)]


def test_loads_with_one_located_warning_and_forbes_sag(synth):
    """One ZemaxWarning at the TYPE line naming Forbes' reading, that OpticStudio's is not
    documented, and the option; the sag equals the closed form ``c r²/(1 + sqrt(1 − (1+k)c²r²))
    + sqrt((1 − k c² r²)/(1 − (1+k) c² r²)) x(1 − x) Σ a_m Q_m(x)`` with Forbes 2007's ``Q0 =
    1``, ``Q1 = (13 − 16x)/√19``, ``Q2 = √(2/95)(29 − 4x(25 − 19x))``, ``x = r²/ρ_n²``."""
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        lens = read_zmx(synth)
    found = _qbfs_warnings(rec)
    assert len(found) == 1, [str(w.message) for w in rec]
    w = found[0]
    assert w.line == _type_line(synth) and w.feature == "TYPE"
    msg = str(w)
    assert msg.startswith(f"{synth}:{w.line}: SURF 1:")
    for part in ("conic base", "Forbes' conic generalisation", "optiland", "not documented",
                 "qbfs_conic='refuse'", "--qbfs-conic refuse"):
        assert part in msg, msg
    s = lens.surfaces[0]
    assert isinstance(s, QType) and s.kind == "qbfs" and float(s.k) == K
    r = np.array([0.0, 0.7, 1.9, 3.2, 4.4, 5.3, 6.0])
    s2, x = r * r, r * r / RN ** 2
    q = [np.ones_like(x), (13 - 16 * x) / math.sqrt(19),
         math.sqrt(2 / 95) * (29 - 4 * x * (25 - 19 * x))]
    phi = np.sqrt((1 - K * C * C * s2) / (1 - (1 + K) * C * C * s2))
    z = C * s2 / (1 + np.sqrt(1 - (1 + K) * C * C * s2)) + phi * x * (1 - x) * sum(
        a * qm for a, qm in zip(A, q))
    rt = torch.tensor(r, dtype=F64)
    zd = s.sag(rt, torch.zeros_like(rt)).detach().numpy()
    assert np.abs(zd - z).max() < 1e-14 * 10   # float64 round-off of a ~0.6 mm sag
    assert abs(z[-1]) > 0.5


def test_refuse_option_refuses_at_the_type_line(synth, capsys):
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(synth, qbfs_conic="refuse")
    assert e.value.line == _type_line(synth) and e.value.feature == "TYPE"
    assert "Qbfs surface on a conic base" in str(e.value)
    assert "qbfs_conic='forbes'" in str(e.value)
    with pytest.raises(ZemaxFileError):   # through load_lens too
        load_lens(synth, qbfs_conic="refuse")
    with pytest.raises(ValueError, match="qbfs_conic must be one of"):
        read_zmx(synth, qbfs_conic="sphere")
    # on the command line
    from deeplens.cli import main

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["report", str(synth), "--qbfs-conic", "refuse", "--sampling", "hexapolar:3"])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == 2 and out == "" and len(lines) == 1
    assert f"{synth}:{_type_line(synth)}:" in lines[0] and "Qbfs" in lines[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["report", str(synth), "--qbfs-conic", "forbes", "--sampling", "hexapolar:3"])
    assert rc == 0 and "EFL" in capsys.readouterr().out


def test_qbfs_on_a_sphere_and_qcon_on_a_conic_load_without_the_warning(synth, tmp_path):
    """The warning is the conic case's only: a Qbfs on a sphere (CONI 0) and a Qcon on a conic
    are defined (Forbes 2007), read silently, and read under ``"refuse"`` too."""
    for name, text in (("sphere.zmx", _SYNTH.replace(f"CONI {K!r}", "CONI 0")),
                       ("qcon.zmx", _SYNTH.replace("XDAT 1 0 ", "XDAT 1 1 "))):
        p = tmp_path / name
        p.write_text(text)
        for opt in ("forbes", "refuse"):
            with warnings.catch_warnings(record=True) as rec:
                warnings.simplefilter("always")
                read_zmx(p, qbfs_conic=opt)
            assert not _qbfs_warnings(rec), name


# ---------------------------------------------------------------- the real file's evidence

def _qbfs_polynomials(n):
    """``Q^bfs_m`` (m < n) as numpy polynomials in ``x``, built here by Gram–Schmidt of
    ``1, x, x², ...`` so that the slopes ``d/du[u²(1 − u²) Q_m(u²)]`` are orthonormal under
    ``(1 − u²)^(-1/2)/(π/2)`` on [0, 1] (Forbes 2007; Gauss–Chebyshev quadrature, exact for
    these degrees), sign ``Q_m(0) > 0``."""
    P = np.polynomial.Polynomial
    m = 64
    u = np.cos((2 * np.arange(1, m + 1) - 1) * np.pi / (2 * m))

    def slope(p):   # d/du [u²(1−u²) p(u²)] at the nodes
        c = np.zeros(2 * len(p.coef) + 4)
        for j, b in enumerate(p.coef):
            c[2 * j + 2] += b
            c[2 * j + 4] -= b
        return P(c).deriv()(u)

    def inner(p, q):
        return float(np.mean(slope(p) * slope(q)))

    out = []
    for j in range(n):
        v = P([0.0] * j + [1.0])
        for q in out:
            v = v - inner(v, q) * q
        v = v / math.sqrt(inner(v, v))
        out.append(v if v(0.0) > 0 else -v)
    return out


def _file_prescription():
    """SURF 1's curvature, conic, ρ_n and coefficients, the two gaps and the semi-diameter of
    the pupil (ENPD / 2), read from the file's lines here."""
    from deeplens.optics.io.agf import decode_zemax_text

    rec, surf = {"gaps": []}, None
    for ln in decode_zemax_text(REAL).splitlines():
        t = ln.split()
        if not t:
            continue
        if t[0] == "SURF":
            surf = int(t[1])
        elif t[0] == "ENPD":
            rec["ENPD"] = float(t[1])
        elif t[0] == "DISZ":
            rec["gaps"].append(t[1])
        elif surf == 1 and t[0] in ("CURV", "CONI"):
            rec[t[0]] = float(t[1])
        elif surf == 1 and t[0] == "XDAT":
            rec[f"XDAT{t[1]}"] = float(t[2])
    n = int(rec["XDAT2"])
    return dict(c=rec["CURV"], k=rec["CONI"], rn=rec["XDAT3"],
                a=[rec[f"XDAT{j + 4}"] for j in range(n)],
                t1=float(rec["gaps"][1]), t2=float(rec["gaps"][2]), R=rec["ENPD"] / 2)


def _meridional_spot(pr, n_glass, factor, rings=12):
    """On-axis collimated rays at the hexapolar pattern's heights (``rings`` rings of ``6 i``
    rays at ``i R / rings``) through the Qbfs face (sag ``z_c + φ x(1−x) Σ a_m Q_m``, slope by
    autograd), the glass, the flat back face and the gap to the file's image plane: the RMS
    spot radius (mm, about the axis: the centroid by symmetry), the rays kept, the image-space
    NA of the rim ray.  ``factor``: ``"forbes"`` ``sqrt((1 − k c² r²)/(1 − (1+k)c² r²))``,
    ``"none"`` 1, ``"sphere"`` ``1/sqrt(1 − c² r²)`` (rays beyond ``1/c`` lost)."""
    c, k, rn = pr["c"], pr["k"], pr["rn"]
    qs = _qbfs_polynomials(len(pr["a"]))
    dep_poly = sum((a * q for a, q in zip(pr["a"], qs)), np.polynomial.Polynomial([0.0]))
    coef = torch.tensor(dep_poly.coef, dtype=F64)
    i = torch.arange(rings + 1, dtype=F64)
    r = (i * pr["R"] / rings).requires_grad_(True)
    w = torch.where(i == 0, torch.ones_like(i), 6 * i)
    s = r * r
    x = s / rn ** 2
    poly = sum(b * x ** j for j, b in enumerate(coef))
    phi = {"forbes": torch.sqrt((1 - k * c * c * s) / (1 - (1 + k) * c * c * s)),
           "none": torch.ones_like(s),
           "sphere": 1 / torch.sqrt(1 - c * c * s)}[factor]
    z = c * s / (1 + torch.sqrt(1 - (1 + k) * c * c * s)) + phi * x * (1 - x) * poly
    (dz,) = torch.autograd.grad(z.nansum(), r)
    z, r = z.detach(), r.detach()
    nrm = torch.stack([-dz, torch.ones_like(dz)]) / torch.sqrt(1 + dz * dz)   # (y, z)
    mu = 1.0 / n_glass
    cos_i = nrm[1]                                   # the ray (0, 1) . the normal
    cos_t = torch.sqrt(1 - mu * mu * (1 - cos_i * cos_i))
    d = torch.stack([torch.zeros_like(r), torch.ones_like(r)]) * mu + (cos_t - mu * cos_i) * nrm
    y2 = r + d[0] * (pr["t1"] - z) / d[1]            # on the flat back face
    sy = n_glass * d[0]                              # refracted there into air
    y3 = y2 + sy * pr["t2"] / torch.sqrt(1 - sy * sy)
    ok = torch.isfinite(y3)
    rms = math.sqrt(float((w[ok] * y3[ok] ** 2).sum() / w[ok].sum()))
    return rms, int(w[ok].sum()), abs(float(sy[-1]))


@pytest.fixture(scope="module")
def asl():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(REAL)


def test_the_real_files_design_decides_the_reading(asl):
    """ASL5040-UV (Thorlabs, UV fused silica, NA 0.65, 40 mm): on axis at its design (primary)
    wavelength, 405 nm, on the file's own image plane, the RMS spot under Forbes' reading is
    below the Airy radius ``1.22 λ F#`` (``F# = 1/(2 NA)``, NA of the traced rim ray), deeplens'
    trace of the loaded lens agrees with the independent trace, and the two other readings are
    more than 100 times worse (measured: Forbes 0.281 µm against an Airy radius of 0.380 µm at
    NA 0.650; no factor 214 µm; the sphere's factor 24 mm over the 271 of 469 rays inside
    r = 1/c = 17.4 mm, the others lost)."""
    from deeplens.analysis.spot import spot_diagram

    pr = _file_prescription()
    wl = float(asl.spec.primary_wavelength_nm)
    assert wl == pytest.approx(405.0)
    n_glass = float(asl.materials[1].n(wl))
    assert pr["t1"] == pytest.approx(float(asl.z_vertices()[1]))
    assert pr["t1"] + pr["t2"] == pytest.approx(float(asl.z_sensor()))
    forbes, n_ok, na = _meridional_spot(pr, n_glass, "forbes")
    airy = 1.22 * wl * 1e-6 / (2 * na)
    assert n_ok == 469 and 0.6 < na < 0.7
    assert forbes < airy, (forbes, airy)
    with torch.no_grad():
        spot = spot_diagram(asl, 0.0, wl, "hexapolar:12", pupil="paraxial")
    assert spot.n_rays == 469
    # the two float64 traces differ by round-off and deeplens' Newton tolerance (< 1e-12 mm
    # on a 2.8e-4 mm spot: measured 1e-12 relative); 1e-6 leaves room for both
    assert float(spot.rms_radius) == pytest.approx(forbes, rel=1e-6)
    none, n_none, _ = _meridional_spot(pr, n_glass, "none")
    sphere, n_sphere, _ = _meridional_spot(pr, n_glass, "sphere")
    assert n_none == 469 and 0 < n_sphere < 469
    assert none > 100 * airy and sphere > 100 * airy, (none, sphere, airy)
    assert none > 100 * forbes and sphere > 100 * forbes
