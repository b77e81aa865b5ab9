"""Every number of the table ``deeplens eval`` / ``eval.py`` prints, recomputed from the per-seed
test metrics with numpy (issue 25, "tests that a wrong implementation must not pass"): PSNR
mean ± sample standard deviation (ddof 1) and SSIM mean per depth and band, and the mean over
depths (per seed first, then over seeds)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from deeplens.evaluation.evaluate import format_table, summarize

DEPTHS, BANDS = [4500.0, 8000.0], [0.0, 0.5, 1.0]


def _metrics(rng):
    m = {}
    for img in ("sensor", "restored"):
        for d in DEPTHS:
            m[f"test/psnr_{img}/d{d:g}mm"] = float(rng.uniform(20, 32))
            m[f"test/ssim_{img}/d{d:g}mm"] = float(rng.uniform(0.5, 0.95))
        for k in range(len(BANDS) - 1):
            m[f"test/psnr_{img}/band{BANDS[k]:g}-{BANDS[k + 1]:g}"] = float(rng.uniform(20, 32))
            m[f"test/ssim_{img}/band{BANDS[k]:g}-{BANDS[k + 1]:g}"] = float(rng.uniform(.5, .95))
    return m


def _cell(text):
    nums = [float(v) for v in re.findall(r"\d+\.\d+", text)]
    return nums  # psnr[, std], ssim


def _check(got, want):
    """PSNR (and its std) printed to 2 decimals, SSIM to 3."""
    assert len(got) == len(want)
    for g, w in zip(got[:-1], want[:-1]):
        assert g == pytest.approx(w, abs=0.0051)
    assert got[-1] == pytest.approx(want[-1], abs=5.1e-4)


@pytest.mark.parametrize("n_seeds", [1, 3])
def test_every_cell_of_the_table_is_the_seed_statistics(n_seeds):
    rng = np.random.default_rng(n_seeds)
    runs = {"no plate": [_metrics(rng) for _ in range(n_seeds)],
            "learned plate": [_metrics(rng) for _ in range(n_seeds)]}
    columns = [(f"{d:g}", f"d{d:g}mm") for d in DEPTHS] + [
        (f"band {BANDS[k]:g}-{BANDS[k + 1]:g}", f"band{BANDS[k]:g}-{BANDS[k + 1]:g}")
        for k in range(len(BANDS) - 1)]
    table = format_table(summarize(runs, DEPTHS, BANDS), columns)
    lines = table.splitlines()
    assert lines[0] == ("| variant | image | 4.5 m | 8 m | band 0-0.5 | band 0.5-1 | "
                        "mean over depths |")
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines[2:]]
    assert [(r[0], r[1]) for r in rows] == [(v, img) for v in runs
                                            for img in ("sensor", "restored")]
    for r in rows:
        seeds = runs[r[0]]
        for cell, (_, suffix) in zip(r[2:-1], columns):
            p = np.array([m[f"test/psnr_{r[1]}/{suffix}"] for m in seeds])
            s = np.array([m[f"test/ssim_{r[1]}/{suffix}"] for m in seeds])
            want = [p.mean()] + ([p.std(ddof=1)] if n_seeds > 1 else []) + [s.mean()]
            _check(_cell(cell), want)
        p = np.array([np.mean([m[f"test/psnr_{r[1]}/d{d:g}mm"] for d in DEPTHS]) for m in seeds])
        s = np.array([np.mean([m[f"test/ssim_{r[1]}/d{d:g}mm"] for d in DEPTHS]) for m in seeds])
        want = [p.mean()] + ([p.std(ddof=1)] if n_seeds > 1 else []) + [s.mean()]
        _check(_cell(r[-1]), want)


def test_summary_worst_depth_and_spread():
    rng = np.random.default_rng(7)
    runs = {"v": [_metrics(rng) for _ in range(2)]}
    e = summarize(runs, DEPTHS)["v"]
    mean = {f"{d:g}": np.mean([m[f"test/psnr_restored/d{d:g}mm"] for m in runs["v"]])
            for d in DEPTHS}
    worst = min(mean, key=mean.get)
    assert e["worst"]["depth_mm"] == float(worst)
    assert e["spread_db"] == pytest.approx(max(mean.values()) - min(mean.values()), abs=1e-12)
