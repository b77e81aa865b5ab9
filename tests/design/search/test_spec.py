"""The design-search specification: values, defaults, files and the errors they raise."""

from __future__ import annotations

import json
import math

import pytest

from deeplens.design.search.spec import DesignSpec, SpecError, glass_set


def test_derived_values_and_defaults():
    s = DesignSpec(efl_mm=50, fno=5, hfov_deg=20, elements=3)
    assert s.epd == 10.0 and s.f_number == 5.0
    assert s.fields_deg == [0.0, 14.0, 20.0]
    assert s.primary_wavelength_nm == 587.5618      # the middle of the sorted list
    assert s.stop_positions() == ["front", 0, 1, "back"]
    assert DesignSpec(efl_mm=50, epd_mm=10, hfov_deg=0, stop="middle").stop_positions() == [1]
    assert DesignSpec(efl_mm=50, epd_mm=10, hfov_deg=0, elements=4,
                      stop="middle").stop_positions() == [1]
    assert DesignSpec(efl_mm=50, epd_mm=10, hfov_deg=0, elements=1,
                      stop="middle").stop_positions() == ["front"]
    assert s.wavelength_weights == (1.0, 1.0, 1.0)


def test_glass_sets():
    schott = glass_set("SCHOTT")
    assert "N-BK7" in schott and "N-SF2" in schott and "FUSED_SILICA" not in schott
    assert all("/" in g for g in glass_set("model"))
    assert glass_set("N-BK7, F2") == ["N-BK7", "F2"]
    with pytest.raises(SpecError, match="'glasses'.*unknown glass 'N-BK77'"):
        glass_set("N-BK77")


@pytest.mark.parametrize("kw,match", [
    (dict(efl_mm=-5, fno=4, hfov_deg=5), "'efl_mm': expected a positive"),
    (dict(efl_mm=50, hfov_deg=5), "exactly one of fno and epd_mm"),
    (dict(efl_mm=50, fno=4, epd_mm=10, hfov_deg=5), "exactly one of fno and epd_mm"),
    (dict(efl_mm=50, fno=4, hfov_deg=75), "'hfov_deg'.*\\[0, 60\\)"),
    (dict(efl_mm=50, fno=4, hfov_deg=5, wavelengths_nm=[0.5876]), "micrometres"),
    (dict(efl_mm=50, fno=4, hfov_deg=5, wavelength_weights=[1, 2]), "expected 3 non-negative"),
    (dict(efl_mm=50, fno=4, hfov_deg=5, elements=0), "'elements'.*1..8"),
    (dict(efl_mm=50, fno=4, hfov_deg=5, elements=2, stop=3), "'stop'.*0..0"),
    (dict(efl_mm=50, fno=4, hfov_deg=5, stop="middel"), "'stop'.*front, middle"),
    (dict(efl_mm=50, fno=4, hfov_deg=5, aspheres=9), "'aspheres'.*0..6"),
    (dict(efl_mm=50, fno=4, hfov_deg=5, field_fractions=[0, 1.5]), "'field_fractions'"),
    (dict(efl_mm=50, fno=4, hfov_deg=5, max_track_mm=0), "'max_track_mm'"),
])
def test_bad_values_name_the_field(kw, match):
    with pytest.raises(SpecError, match=match):
        DesignSpec(**kw)


def test_files_round_trip_and_errors(tmp_path):
    yaml = pytest.importorskip("yaml")
    s = DesignSpec(efl_mm=101.18, fno=3.464, hfov_deg=11.86, max_track_mm=130, stop=1)
    p = tmp_path / "cooke.yaml"
    p.write_text(yaml.safe_dump(s.to_dict()))
    assert DesignSpec.from_file(p) == s
    q = tmp_path / "cooke.json"
    q.write_text(json.dumps(s.to_dict()))
    t = DesignSpec.from_file(q)
    assert t == s and math.isinf(t.object_distance_mm)
    p.write_text("efl_mm: 50\nfno: 4\nhfov_deg: 5\nmax_trak_mm: 60\n")
    with pytest.raises(SpecError, match=r"cooke.yaml, field 'max_trak_mm'.*'max_track_mm'"):
        DesignSpec.from_file(p)
    p.write_text("fno: 4\nhfov_deg: 5\n")
    with pytest.raises(SpecError, match=r"cooke.yaml, field 'efl_mm': this field is required"):
        DesignSpec.from_file(p)
    p.write_text("efl_mm: 50\nfno: 4\nhfov_deg: 5\nstop: sideways\n")
    with pytest.raises(SpecError, match=r"cooke.yaml, field 'stop'"):
        DesignSpec.from_file(p)
    with pytest.raises(SpecError, match="expected a .yaml, .yml or .json"):
        (tmp_path / "x.txt").write_text("")
        DesignSpec.from_file(tmp_path / "x.txt")
