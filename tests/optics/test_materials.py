"""Tests for deeplens.optics.materials: catalogue data against published n_d / V_d, the model
glass closed form, the air convention, name handling and wavelength checks."""

import math

import pytest
import torch

from deeplens.optics.materials import (
    GLASS_TABLE, LINE_C, LINE_D, LINE_F, WAVELENGTH_UNIT, Air, Material, ModelGlass,
    SchottFormulaGlass, SellmeierGlass, UnknownMaterialError, catalogue, check_wavelength_nm,
    get_material,
)

REQUIRED = [
    "N-BK7", "N-SF5", "SF5", "N-SF6", "N-SF2", "N-SF10", "SF10", "N-SF11", "N-BAF10", "N-BAK1",
    "N-BAK4", "N-SK16", "N-SSK8", "F2", "N-F2", "N-LAK9", "N-LAK22", "N-LASF9", "N-LASF44",
    "N-K5", "N-PSK53A", "SK16", "FUSED_SILICA", "SILICA", "F_SILICA", "PMMA", "PC",
    "POLYCARBONATE", "B270", "SSK4", "SK1", "F15", "AIR", "VACUUM", "OCCLUDER",
]


def _n(m: Material, w: float) -> float:
    return float(m.n(torch.tensor(w, dtype=torch.float64)))


def test_constants():
    assert WAVELENGTH_UNIT == "nm"
    assert (LINE_D, LINE_F, LINE_C) == (587.5618, 486.1327, 656.2725)


def test_catalogue_has_required_names():
    names = catalogue()
    assert names == sorted(names)
    missing = [n for n in REQUIRED if n not in names]
    assert not missing


@pytest.mark.parametrize("name", sorted(GLASS_TABLE))
def test_catalogue_glass_matches_published_nd_vd(name):
    rec = GLASS_TABLE[name]
    m = get_material(name)
    n_d = _n(m, LINE_D)
    v_d = (n_d - 1.0) / (_n(m, LINE_F) - _n(m, LINE_C))
    assert abs(n_d - rec.nd) <= 2e-5, (name, n_d, rec.nd)
    assert abs(v_d - rec.vd) <= 0.05, (name, v_d, rec.vd)
    assert m.nd == pytest.approx(n_d, abs=1e-15)
    assert m.vd == pytest.approx(v_d, rel=1e-12)
    lo, hi = m.wavelength_range_nm
    assert lo <= LINE_F and LINE_C <= hi


def test_catalogue_classes():
    assert isinstance(get_material("N-BK7"), SellmeierGlass)
    assert isinstance(get_material("FUSED_SILICA"), SellmeierGlass)
    for name in ("B270", "PMMA", "PC"):
        assert isinstance(get_material(name), SchottFormulaGlass)
    for name in ("SSK4", "SK1", "F15", "SK16"):
        assert isinstance(get_material(name), ModelGlass)


def test_nbk7_f_and_c_lines():
    m = get_material("N-BK7")
    assert _n(m, 486.1327) == pytest.approx(1.52238, abs=1e-5)
    assert _n(m, 656.2725) == pytest.approx(1.51432, abs=1e-5)


def test_b270_against_1993_data_sheet():
    # SCHOTT B 270 data sheet (Aug 1993), 4 decimals; the catalogue formula differs by <= 1e-4.
    m = get_material("B270")
    table = {435.83: 1.5341, 479.99: 1.5297, 486.13: 1.5292, 546.07: 1.5251, 587.56: 1.5230,
             589.29: 1.5229, 643.85: 1.5207, 656.27: 1.5203}
    for w, n in table.items():
        assert _n(m, w) == pytest.approx(n, abs=1.5e-4), w


def test_sf5_and_n_sf5_are_different_glasses():
    a, b = get_material("SF5"), get_material("N-SF5")
    assert a.to_spec() == "SF5" and b.to_spec() == "N-SF5"
    assert abs(_n(a, 450.0) - _n(b, 450.0)) > 1e-5


@pytest.mark.parametrize("n_d,v_d", [(1.5168, 64.17), (1.6177, 55.116), (1.9, 20.0), (1.3, 90.0)])
def test_model_glass_closed_form(n_d, v_d):
    m = get_material(f"{n_d}/{v_d}")
    assert isinstance(m, ModelGlass)
    lf, lc, ld = LINE_F / 1e3, LINE_C / 1e3, LINE_D / 1e3
    B = (n_d - 1) / (v_d * (1 / lf ** 2 - 1 / lc ** 2))
    A = n_d - B / ld ** 2
    assert m.B == pytest.approx(B, rel=1e-15) and m.A == pytest.approx(A, rel=1e-15)
    n = m.n(torch.tensor([LINE_D, LINE_F, LINE_C], dtype=torch.float64)).tolist()
    assert n[0] == pytest.approx(n_d, abs=1e-13)
    assert (n[0] - 1) / (n[1] - n[2]) == pytest.approx(v_d, rel=1e-11)
    w = 500.0
    assert _n(m, w) == pytest.approx(A + B / (w / 1e3) ** 2, abs=1e-14)


def test_model_glass_catalogue_entries_exact_at_d():
    for name, (nd, vd) in {"SSK4": (1.61770, 55.116), "SK1": (1.61030, 56.712),
                           "F15": (1.60570, 37.831), "SK16": (1.62040, 60.306)}.items():
        m = get_material(name)
        assert m.nd == pytest.approx(nd, abs=1e-13)
        assert m.vd == pytest.approx(vd, rel=1e-11)


def test_model_glass_infinite_abbe_is_non_dispersive():
    m = get_material("1.5/inf")
    n = m.n(torch.tensor([400.0, 700.0], dtype=torch.float64))
    assert torch.all(n == 1.5)
    assert m.vd == math.inf


@pytest.mark.parametrize("name", ["AIR", "air", "Vacuum", "OCCLUDER", "occluder"])
def test_air_is_exactly_one(name):
    m = get_material(name)
    assert isinstance(m, Air)
    for w in (587.5618, torch.linspace(380, 780, 7), torch.full((2, 3), 550.0)):
        n = m.n(w)
        assert torch.all(n == 1.0)
        if isinstance(w, torch.Tensor):
            assert n.shape == w.shape and n.dtype == w.dtype
    assert m.nd == 1.0 and m.vd == math.inf
    assert m.to_spec() == name.upper()
    assert get_material(m.to_spec()).name == name.upper()


def test_case_insensitive_names_and_aliases():
    assert get_material("n-bk7").to_spec() == "N-BK7"
    assert get_material("  N-bk7 ").to_spec() == "N-BK7"
    assert get_material("sf5").to_spec() == "SF5"
    assert get_material("n-sf5").to_spec() == "N-SF5"
    assert get_material("n-psk53a").to_spec() == "N-PSK53A"
    for alias in ("fused_silica", "silica", "F_SILICA", "fused silica"):
        assert get_material(alias).to_spec() == "FUSED_SILICA"
    for alias in ("pc", "Polycarbonate", "POLYCARB"):
        assert get_material(alias).to_spec() == "PC"
    assert get_material("pmma").to_spec() == "PMMA"
    assert get_material("b270").to_spec() == "B270"


@pytest.mark.parametrize("spec", catalogue() + ["1.5168/64.17", "1.7/30.5", "1.5/inf"])
def test_to_spec_round_trip(spec):
    m = get_material(spec)
    m2 = get_material(m.to_spec())
    assert type(m2) is type(m)
    assert m2.to_spec() == m.to_spec()
    assert m2.wavelength_range_nm == m.wavelength_range_nm
    w = torch.tensor([450.0, LINE_D, 650.0], dtype=torch.float64)
    assert torch.equal(m.n(w), m2.n(w))


def test_model_spec_string():
    assert get_material("1.5168/64.17").to_spec() == "1.5168/64.17"
    assert ModelGlass(1.5168, 64.17).to_spec() == "1.5168/64.17"
    assert ModelGlass(1.6177, 55.116, name="not-a-catalogue-name").to_spec() == "1.6177/55.116"


def test_get_material_returns_new_instances():
    a, b = get_material("N-BK7"), get_material("N-BK7")
    assert a is not b
    assert isinstance(a, torch.nn.Module)


def test_unknown_glass_names_closest_matches():
    with pytest.raises(UnknownMaterialError) as exc:
        get_material("N-BK8")
    err = exc.value
    assert isinstance(err, ValueError)
    msg = str(err)
    assert "'N-BK8'" in msg and "closest known:" in msg
    assert len(err.suggestions) == 3
    assert err.suggestions[0] == "N-BK7"
    for s in err.suggestions:
        assert s in msg and s in catalogue()
    with pytest.raises(UnknownMaterialError, match="N-LASF9"):
        get_material("n-lasf99")


@pytest.mark.parametrize("spec,words", [
    ("abc/def", "n_d/V_d"), ("1.5/", "n_d/V_d"), ("1.5/60/2", "n_d/V_d"),
    ("0.9/50", "n_d"), ("1.5/0", "V_d"), ("1.5/-3", "V_d"), ("nan/50", "n_d"), ("1.5/nan", "V_d"),
    ("0/inf", "n_d"), ("-0.5/inf", "n_d"),
])
def test_malformed_model_spec(spec, words):
    with pytest.raises(ValueError, match="expected 'n_d/V_d'") as exc:
        get_material(spec)
    assert not isinstance(exc.value, UnknownMaterialError)
    assert words in str(exc.value) and spec in str(exc.value)


def test_non_dispersive_relative_index_below_one():
    """A non-dispersive model glass may have 0 < n_d < 1 (an index relative to air: a vacuum or
    purge-gas gap in a lithography lens); its index is the same at every wavelength, so it has
    no wavelength range; a dispersive one below 1 is refused."""
    m = get_material("0.999712/inf")
    assert isinstance(m, ModelGlass) and m.wavelength_range_nm == (0.0, math.inf)
    w = torch.tensor([150.0, 193.304, 587.5618, 1e4], dtype=torch.float64)
    assert torch.equal(m.n(w), torch.full_like(w, 0.999712))
    assert get_material(m.to_spec()).n(193.0) == m.n(193.0)
    with pytest.raises(ValueError, match="V_d = inf"):
        ModelGlass(0.999712, 50.0)
    assert ModelGlass(1.5, 50.0).wavelength_range_nm == (310.0, 2500.0)


def test_non_string_spec():
    with pytest.raises(TypeError):
        get_material(1.5168)


def test_micrometre_wavelength_error():
    m = get_material("N-BK7")
    with pytest.raises(ValueError) as exc:
        m.n(0.5876)
    msg = str(exc.value)
    assert "nanometres" in msg and "micrometres" in msg and "0.5876" in msg and "587.6" in msg
    with pytest.raises(ValueError, match="micrometres"):
        m.n(torch.tensor([0.45, 0.55, 0.65]))
    with pytest.raises(ValueError, match="micrometres"):
        check_wavelength_nm([0.486, 0.588])


def test_picometre_and_invalid_wavelength_errors():
    with pytest.raises(ValueError, match="picometres"):
        check_wavelength_nm(587562.0)
    for bad in (float("nan"), float("inf"), 0.0, -550.0):
        with pytest.raises(ValueError, match="finite and > 0"):
            check_wavelength_nm(torch.tensor([550.0, bad]))
    with pytest.raises(ValueError, match="below 10 nm"):
        check_wavelength_nm([1.0, 550.0])
    with pytest.raises(ValueError, match="^lens wavelengths: "):
        check_wavelength_nm(0.55, where="lens wavelengths: ")
    with pytest.raises(ValueError, match="^tracing: "):
        check_wavelength_nm(-1.0, where="tracing")
    check_wavelength_nm(torch.empty(0))
    check_wavelength_nm([450.0, 550.0, 650.0])
    check_wavelength_nm(torch.tensor([550], dtype=torch.int64))


def test_out_of_range_wavelength_names_material():
    m = get_material("N-SF6")   # SCHOTT range 370-2500 nm
    with pytest.raises(ValueError) as exc:
        m.n(torch.tensor([350.0, 550.0]))
    msg = str(exc.value)
    assert "N-SF6" in msg and "350" in msg and "370" in msg and "2500" in msg
    with pytest.raises(ValueError, match="N-SF6"):
        check_wavelength_nm(3000.0, m)
    m.n(torch.tensor([370.0, 2500.0]))   # the ends are inside


def test_dtype_shape_and_gradient():
    m = get_material("N-BK7")
    n = m.n(550.0)
    assert isinstance(n, torch.Tensor) and n.dtype == torch.float64 and n.shape == ()
    assert m(550.0).item() == n.item()

    w64 = torch.tensor([[486.1327, 587.5618], [656.2725, 550.0]], dtype=torch.float64,
                       requires_grad=True)
    n64 = m.n(w64)
    assert n64.dtype == torch.float64 and n64.shape == w64.shape
    n64.sum().backward()
    assert w64.grad is not None and w64.grad.dtype == torch.float64
    assert torch.all(w64.grad < 0)   # normal dispersion: dn/dλ < 0
    assert torch.autograd.gradcheck(m.n, (w64.detach().clone().requires_grad_(),))

    w32 = torch.tensor([486.1327, 587.5618, 656.2725], dtype=torch.float32, requires_grad=True)
    n32 = m.n(w32)
    assert n32.dtype == torch.float32
    assert torch.allclose(n32.double(), m.n(w32.detach().double()), atol=1e-6)
    n32.sum().backward()
    assert w32.grad.dtype == torch.float32 and torch.all(torch.isfinite(w32.grad))

    assert m.n(torch.tensor([550], dtype=torch.int64)).dtype == torch.float64


@pytest.mark.parametrize("name", ["N-SF11", "PMMA", "SK1", "FUSED_SILICA"])
def test_gradient_every_kind(name):
    m = get_material(name)
    w = torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(m.n, (w,))
    m.n(w).sum().backward()
    assert torch.all(w.grad < 0)


def test_module_conversions_do_not_change_coefficients():
    m = get_material("N-BK7")
    before = _n(m, 550.0)
    m.float()
    m.half()
    assert _n(m, 550.0) == before


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_device_preserved():
    w = torch.tensor([450.0, 550.0, 650.0], device="cuda", dtype=torch.float32)
    for name in ("N-BK7", "PMMA", "SK1", "AIR"):
        m = get_material(name).to("cuda")
        n = m.n(w)
        assert n.device == w.device and n.dtype == torch.float32
        assert torch.allclose(n.cpu().double(), m.n(w.cpu().double()), atol=1e-6)


def test_out_of_range_wavelength_message_shows_the_value_that_is_out():
    """Regression (issue 12, defect 7): 2500.001 nm was reported as "2500 nm is outside
    300-2500" (6 significant digits); the value is printed with the digits that tell it from
    the range's edge."""
    from deeplens.optics.materials import check_wavelength_nm, get_material

    glass = get_material("N-BK7")
    lo, hi = glass.wavelength_range_nm
    with pytest.raises(ValueError, match=rf"wavelength {hi:g}\.001 nm is outside"):
        check_wavelength_nm(hi + 0.001, glass)
    with pytest.raises(ValueError, match=r"wavelength 299\.9999999 nm is outside"):
        check_wavelength_nm([299.9999999, 500.0], glass)
    with pytest.raises(ValueError, match=r"wavelength 2600 nm is outside"):
        check_wavelength_nm(2600.0, glass)
