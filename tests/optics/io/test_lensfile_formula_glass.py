"""A JSON lens file keeps glasses that ``get_material`` does not know by name.

A ``.zmx`` file may name a vendor glass (OHARA's ``S-LAH64``), an archived or previous-catalogue
glass or a user's ``.agf`` glass; ``save_lens(lens, "x.json")`` once wrote only the name, and the
file could not be read back ("unknown glass 'S-LAH64'").  Such a glass is now written with its
dispersion formula; these tests check the round trip is exact (every index bit for bit, the EFL
to the last digit), that a glass the built-in catalogue gives back identically is still written
by name, and that a malformed formula entry is refused with its JSON path.
"""

import copy
import json

import pytest
import torch

from deeplens.optics.errors import LensFileError
from deeplens.optics.io import load_lens, save_lens
from deeplens.optics.io.agf import AGFGlass
from deeplens.optics.io.lensfile import lens_from_dict, lens_to_dict
from deeplens.optics.io.vendor_glass import BuchdahlGlass, previous_glass
from deeplens.optics.paraxial import paraxial

W = torch.tensor([486.1327, 587.5618, 656.2725], dtype=torch.float64)


@pytest.fixture(scope="module")
def cots():
    """A real file naming OHARA's S-LAH64 (found by exact name outside the catalogues GCAT
    names: loading it reads the vendor catalogues once)."""
    with pytest.warns(Warning):
        return load_lens("tests/data/zmx_real/cots_COTS-0002-12-1.zmx")


def _indices(lens):
    return torch.stack([m.n(W).double() for m in lens.materials])


def test_vendor_glass_round_trips_through_json(tmp_path, cots):
    lens = cots
    assert any(isinstance(m, AGFGlass) and m.name == "S-LAH64" for m in lens.materials)
    save_lens(lens, tmp_path / "x.json")
    data = json.loads((tmp_path / "x.json").read_text())
    entries = [s["material"] for s in data["surfaces"] if isinstance(s["material"], dict)]
    assert [e["glass"] for e in entries] == ["S-LAH64"]
    assert entries[0]["catalogue"] == "OHARA" and entries[0]["agf_formula"] == 2
    back = load_lens(tmp_path / "x.json")
    assert torch.equal(_indices(back), _indices(lens))
    assert float(paraxial(back).efl) == float(paraxial(lens).efl)
    # a glass the built-in catalogue gives back identically is still written by name
    assert all(isinstance(s["material"], str) for s in data["surfaces"]
               if not isinstance(s["material"], dict)) and data["surfaces"][0]["material"]


def test_previous_catalogue_glass_round_trips():
    lens = load_lens("data/lenses/cooke_triplet.json").to(torch.float64)
    lens.spec.wavelengths_nm = [486.1327, 587.5618, 656.2725]
    lens.materials[3] = previous_glass("SF15", "SCHOTT")
    d = lens_to_dict(lens)
    assert d["surfaces"][2]["material"]["buchdahl"][0] == pytest.approx(1.6989, abs=0.01)
    back = lens_from_dict(json.loads(json.dumps(d)), source="mem.json")
    assert isinstance(back.materials[3], BuchdahlGlass)
    assert torch.equal(_indices(back), _indices(lens))


@pytest.mark.parametrize("edit, where", [
    (lambda m: m.pop("agf_formula"), "surfaces[2].material"),
    (lambda m: m.update(buchdahl=[1.6, 0.1, 0.0]), "surfaces[2].material"),
    (lambda m: m.update(wavelength_range_nm=[700.0, 400.0]),
     "surfaces[2].material.wavelength_range_nm"),
    (lambda m: m.update(colour="blue"), "surfaces[2].material.colour"),
    (lambda m: m.update(agf_formula=99), "surfaces[2].material"),
    (lambda m: m.update(coefficients=[-5.0, 0.01, 0.0, 0.03, 0.0, 89.0]),
     "surfaces[2].material"),
])
def test_malformed_formula_glass_is_refused_at_its_path(edit, where):
    lens = load_lens("data/lenses/cooke_triplet.json").to(torch.float64)
    lens.materials[3] = AGFGlass("S-LAH64", 2, [1.83021453, 0.0090482329, 0.29156359,
                                                0.0330756689, 1.28544024, 89.3675501],
                                 (310.0, 2500.0), catalogue="OHARA")
    d = json.loads(json.dumps(lens_to_dict(lens)))
    i = next(k for k, s in enumerate(d["surfaces"]) if isinstance(s["material"], dict))
    assert i == 2
    assert lens_from_dict(d, source="good.json").materials[3].n(W).tolist() == \
        lens.materials[3].n(W).tolist()
    bad = copy.deepcopy(d)
    edit(bad["surfaces"][i]["material"])
    with pytest.raises(LensFileError) as e:
        lens_from_dict(bad, source="bad.json")
    assert where in str(e.value)
