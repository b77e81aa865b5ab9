"""Sizes set by user input are checked before anything is allocated (issue 25, item 1): a clear
error naming the key and the memory it would need, never an allocator traceback or the OOM
killer."""

import copy
import json

import pytest

from deeplens.optics.io import LensFileError, load_lens
from deeplens.optics.limits import MemoryBudgetError, check_allocation, memory_budget_bytes
from deeplens.optics.sampling import RAY_BYTES, parse_sampling, pupil_pattern


def test_budget_comes_from_the_environment_with_units(monkeypatch):
    monkeypatch.setenv("DEEPLENS_MEMORY_BUDGET", "2G")
    assert memory_budget_bytes() == 2 << 30
    monkeypatch.setenv("DEEPLENS_MEMORY_BUDGET", "1500000")
    assert memory_budget_bytes() == 1_500_000
    monkeypatch.setenv("DEEPLENS_MEMORY_BUDGET", "lots")
    with pytest.raises(ValueError, match="DEEPLENS_MEMORY_BUDGET"):
        memory_budget_bytes()
    monkeypatch.delenv("DEEPLENS_MEMORY_BUDGET")
    assert memory_budget_bytes() > 1 << 28  # the machine's physical memory


def test_check_allocation_names_key_and_bytes(monkeypatch):
    monkeypatch.setenv("DEEPLENS_MEMORY_BUDGET", "1M")
    assert check_allocation("k", 1000, 1000, "things") == 1_000_000
    with pytest.raises(MemoryBudgetError, match=r"render\.spp: 2,000,000 rays .* 1.91 MiB") as e:
        check_allocation("render.spp", 2_000_000, 1, "rays")
    assert e.value.key == "render.spp" and e.value.needed == 2_000_000


def test_hexapolar_count_is_checked_before_the_pattern_is_built(monkeypatch):
    monkeypatch.setenv("DEEPLENS_MEMORY_BUDGET", "1G")
    n = 1 + 3 * 3000 * 3001  # hexapolar:3000
    with pytest.raises(MemoryBudgetError, match=r"hexapolar:3000.*27,009,001 rays.*GiB") as e:
        pupil_pattern("hexapolar:3000")
    assert e.value.needed == n * RAY_BYTES
    with pytest.raises(MemoryBudgetError, match="grid:100000"):
        parse_sampling("grid:100000")
    with pytest.raises(MemoryBudgetError, match="random:"):
        parse_sampling(f"random:{10 ** 12}")
    assert pupil_pattern("hexapolar:6").shape == (1 + 3 * 6 * 7, 2)


def _lens_dict():
    return {
        "format": "deeplens-lens", "version": 1, "name": "singlet",
        "units": {"length": "mm", "wavelength": "nm"},
        "object": {"distance_mm": "inf", "medium": "AIR"},
        "aperture": {"type": "stop"}, "fields_deg": [0.0], "wavelengths_nm": [587.6],
        "primary_wavelength_nm": 587.6, "stop": 0,
        "surfaces": [
            {"type": "sphere", "semi_diameter_mm": 5.0, "curvature_per_mm": 0.02,
             "distance_mm": 0.0, "material": "N-BK7"},
            {"type": "plane", "semi_diameter_mm": 5.0, "distance_mm": 3.0, "material": "AIR"}],
        "sensor": {"distance_mm": 45.0, "semi_diameter_mm": 5.0},
    }


def _write(tmp_path, d, text=None):
    p = tmp_path / "lens.json"
    p.write_text(text if text is not None else json.dumps(d))
    return p


def test_a_huge_element_index_is_refused_before_a_range_is_built(tmp_path):
    """A typo of 10^12 in ``elements`` built ``range(0, 10^12)`` first (23 GB, OOM killer)."""
    assert load_lens(_write(tmp_path, _lens_dict())).elements == [(0, 1)]
    d = _lens_dict()
    d["elements"] = [[0, 10 ** 12]]
    with pytest.raises(LensFileError, match=r"elements.*\[0, 1000000000000\].*<= 1"):
        load_lens(_write(tmp_path, d))
    d["elements"] = [[-1, 1]]
    with pytest.raises(LensFileError, match="elements"):
        load_lens(_write(tmp_path, d))


def test_absurd_numbers_in_a_lens_file_are_named(tmp_path):
    """An integer too large for a float, deeply nested JSON and a 1e308 mm thickness (which
    printed an EFL of -1e-305 mm with exit status 0) give errors naming the file and field."""
    d = _lens_dict()
    d["surfaces"][1]["distance_mm"] = 10 ** 400
    with pytest.raises(LensFileError, match=r"surfaces\[1\]\.distance_mm.*401 digits"):
        load_lens(_write(tmp_path, d))
    d = copy.deepcopy(_lens_dict())
    d["surfaces"][1]["distance_mm"] = 1e308
    with pytest.raises(LensFileError, match=r"surfaces\[1\]\.distance_mm.*at most 1e\+12 mm"):
        load_lens(_write(tmp_path, d))
    with pytest.raises(LensFileError, match="nested too deeply"):
        load_lens(_write(tmp_path, None, "[" * 100_000 + "]" * 100_000))
    with pytest.raises(LensFileError, match="unreadable JSON number"):
        load_lens(_write(tmp_path, None, '{"format": ' + "1" * 5000 + "}"))
