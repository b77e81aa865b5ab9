"""Sizes set by user input are checked before anything is allocated (issue 25, item 1): a clear
error naming the key and the memory it would need, never an allocator traceback or the OOM
killer."""

import copy
import os
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


# ---- the process's own limits (issue 38 item 10): ulimit -v, the cgroup's memory limit

def _only(monkeypatch, **found):
    """The budget's sources replaced by ``found`` (name -> (bytes, text) or None)."""
    from deeplens.optics import limits

    monkeypatch.delenv("DEEPLENS_MEMORY_BUDGET", raising=False)
    for name in ("_physical", "_address_space", "_cgroup"):
        monkeypatch.setattr(limits, name, lambda v=found.get(name): v)


def test_the_smallest_limit_is_the_budget_and_the_message_names_it(monkeypatch):
    _only(monkeypatch, _physical=(64 << 30, "this machine's physical memory"),
          _address_space=(3 << 30, "this process's address-space limit (ulimit -v ...)"),
          _cgroup=(8 << 30, "the cgroup memory limit in /x/memory.max"))
    assert memory_budget_bytes() == 3 << 30
    with pytest.raises(MemoryBudgetError, match=r"render\.spp: .* more than the 3 GiB this "
                       r"process may use, set by this process's address-space limit \(ulimit "
                       r"-v") as e:
        check_allocation("render.spp", 4 << 30, 1, "rays")
    assert e.value.budget == 3 << 30
    _only(monkeypatch, _physical=(64 << 30, "this machine's physical memory"),
          _cgroup=(2 << 30, "the cgroup memory limit in /x/memory.max"))
    with pytest.raises(MemoryBudgetError, match=r"2 GiB .* the cgroup memory limit in /x/"):
        check_allocation("render.spp", 3 << 30, 1, "rays")
    assert check_allocation("render.spp", 1 << 30, 1, "rays") == 1 << 30


def test_the_address_space_limit_counts_what_is_already_mapped(monkeypatch):
    import resource

    from deeplens.optics import limits

    monkeypatch.setattr(resource, "getrlimit", lambda which: (
        (5 << 30, resource.RLIM_INFINITY) if which == resource.RLIMIT_AS else (-1, -1)))
    monkeypatch.setattr(limits, "_mapped_bytes", lambda: 2 << 30)
    n, text = limits._address_space()
    assert n == 3 << 30 and "ulimit -v" in text and "5 GiB" in text
    monkeypatch.setattr(resource, "getrlimit",
                        lambda which: (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
    assert limits._address_space() is None


def _tree(root, files):
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)


def test_cgroup_v2_limit_is_the_tightest_along_the_path(tmp_path):
    from deeplens.optics import limits

    root, me = tmp_path / "cg", tmp_path / "self_cgroup"
    me.write_text("0::/system.slice/slurmstepd.scope/job_7/step_0\n")
    _tree(root, {"memory.max": "max\n",
                 "system.slice/slurmstepd.scope/memory.max": "max\n",
                 "system.slice/slurmstepd.scope/job_7/memory.max": f"{3 << 30}\n",
                 "system.slice/slurmstepd.scope/job_7/step_0/memory.max": "max\n"})
    n, text = limits._cgroup(root, me)
    assert n == 3 << 30 and "job_7/memory.max" in text and "--mem" in text
    _tree(root, {"system.slice/slurmstepd.scope/job_7/step_0/memory.max": f"{1 << 30}\n"})
    assert limits._cgroup(root, me)[0] == 1 << 30
    _tree(root, {"system.slice/slurmstepd.scope/job_7/step_0/memory.max": "garbage\n",
                 "system.slice/slurmstepd.scope/job_7/memory.max": "max\n"})
    assert limits._cgroup(root, me) is None     # unlimited or unreadable everywhere
    assert limits._cgroup(tmp_path / "absent", tmp_path / "absent_self") is None


def test_cgroup_v1_limit_and_its_unlimited_value(tmp_path):
    from deeplens.optics import limits

    root, me = tmp_path / "cg", tmp_path / "self_cgroup"
    me.write_text("5:cpu,cpuacct:/a\n4:memory:/slurm/uid_1/job_9\n0::/\n")
    _tree(root, {"memory/memory.limit_in_bytes": "9223372036854771712\n",
                 "memory/slurm/uid_1/job_9/memory.limit_in_bytes": f"{5 << 30}\n",
                 "cpu,cpuacct/a/memory.limit_in_bytes": "1\n"})   # not the memory controller
    n, text = limits._cgroup(root, me)
    assert n == 5 << 30 and "job_9/memory.limit_in_bytes" in text
    _tree(root, {"memory/slurm/uid_1/job_9/memory.limit_in_bytes": "9223372036854771712\n"})
    assert limits._cgroup(root, me) is None


@pytest.mark.slow
def test_a_real_ulimit_v_is_named_instead_of_an_allocator_error(tmp_path):
    """Under ``ulimit -v`` a request that fits in physical memory but not under the limit is
    refused naming the limit (before the patch: torch's raw 'can't allocate memory')."""
    import subprocess
    import sys

    code = ("import os, resource\n"
            "from deeplens.optics import limits\n"
            "soft = resource.getrlimit(resource.RLIMIT_AS)[0]\n"
            "need = soft + (1 << 30)\n"    # more than the whole limit, less than the machine
            "phys = limits._physical()\n"
            "assert phys is None or need < phys[0], 'machine too small for this test'\n"
            "try:\n"
            "    limits.check_allocation('render.spp', need, 1, 'bytes')\n"
            "except limits.MemoryBudgetError as e:\n"
            "    print('REFUSED', e)\n")
    env = {k: v for k, v in os.environ.items() if k != "DEEPLENS_MEMORY_BUDGET"}
    env["OMP_NUM_THREADS"] = "1"
    limit_kib = 8 << 20   # 8 GiB of address space: room for Python and torch's libraries
    r = subprocess.run(["bash", "-c", f'ulimit -v {limit_kib} && exec "$0" -c "$1"',
                        sys.executable, code], capture_output=True, text=True, env=env,
                       timeout=60)
    if "machine too small" in r.stderr:
        pytest.skip("physical memory below the test's 9 GiB request")
    assert r.returncode == 0, r.stderr
    assert "REFUSED render.spp:" in r.stdout and "ulimit -v" in r.stdout, r.stdout
