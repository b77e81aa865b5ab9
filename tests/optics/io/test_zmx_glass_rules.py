"""Which glass a ``GLAS`` line gets: the catalogue glass for a named glass (never the line's
stale n_d/V_d), a fallback that is never silent, and the user's catalogues (reader argument,
``DEEPLENS_GLASS_PATH``, ``--glass-catalog``) in the documented order.

OpticStudio looks a glass name up in the loaded catalogues and uses that glass's coefficients
(its manual, "Using Material Catalogs"); the n_d/V_d columns are the ``Model`` material solve's
parameters ("Material Solves").  A file can carry stale ones: one real file writes
``GLAS H-ZLAF96 0 0 1.959 ...`` where CDGM's H-ZLAF96 has n_d 2.0998.
"""

from __future__ import annotations

import contextlib
import io
import os
import warnings

import pytest
import torch
from test_zmx import line_of, singlet, write

from deeplens.cli import main as cli_main
from deeplens.optics.io import ZemaxFileError, ZemaxWarning, read_zmx
from deeplens.optics.io.zmx_glass import GLASS_PATH_ENV

D = torch.tensor(587.5618, dtype=torch.float64)


def agf(path, glasses: dict):
    """An .agf whose glasses have a constant index (Schott formula, only A0 = n²)."""
    text = "".join(f"NM {g} 1 0 {n!r} 50 0 0 0\nCD {n * n!r} 0 0 0 0 0\nLD 0.3 2.5\n"
                   for g, n in glasses.items())
    path.write_text(text)
    return path


def nd(lens, i=2) -> float:
    return float(lens.materials[i].n(D))


def test_a_named_catalogue_glass_wins_over_the_glas_lines_model_values(tmp_path):
    """``GLAS N-BK7 0 0 1.959 17.47``: SCHOTT's N-BK7 (n_d 1.5168), not a model glass of the
    line's values; the disagreement is one located note."""
    p = write(tmp_path, singlet(glass="GLAS N-BK7 0 0 1.959 17.47 0 0 0 0 0 0"))
    ln = line_of(p.read_text(), "GLAS N-BK7")
    with pytest.warns(ZemaxWarning) as rec:
        lens = read_zmx(p)
    assert nd(lens) == pytest.approx(1.5168, abs=2e-5)
    notes = [str(w.message) for w in rec if "differ" in str(w.message)]
    assert len(notes) == 1 and f"t.zmx:{ln}: glass 'N-BK7': the GLAS line's n_d 1.959" in notes[0]
    assert "the catalogue glass is used" in notes[0]
    # values that agree (as OpticStudio writes them for a glass it evaluated): no note
    with warnings.catch_warnings():
        warnings.simplefilter("error", ZemaxWarning)
        ok = read_zmx(write(tmp_path, singlet(glass="GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0"),
                            "ok.zmx"))
    assert nd(ok) == nd(lens)


def test_a_model_solve_uses_the_lines_values(tmp_path):
    """The model glass (``___BLANK``, or a name with the Model solve, code 1) is the line's."""
    for glass in ("GLAS ___BLANK 1 0 1.959 17.47 0 0 0 0 0 0",
                  "GLAS H-ZLAF96 1 0 1.959 17.47 0 0 0 0 0 0"):
        lens = read_zmx(write(tmp_path, singlet(glass=glass)))
        assert nd(lens) == pytest.approx(1.959, abs=1e-12)


STALE = "GLAS H-ZLAF96 0 0 1.959 17.47 0 0 0 0 0 0"


def test_a_stale_model_value_is_used_only_on_request_and_never_silently(tmp_path):
    p = write(tmp_path, singlet(glass=STALE, gcat="GCAT CDGM"))
    ln = line_of(p.read_text(), "H-ZLAF96")
    with pytest.raises(ZemaxFileError, match=rf"t\.zmx:{ln}: glass 'H-ZLAF96' is not in the "
                                             r"shipped CDGM catalogue; pass the vendor's \.agf "
                                             r"that has it with --glass-catalog$"):
        read_zmx(p)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        lens = read_zmx(p, glass_fallback="model")
    msgs = [str(w.message) for w in rec if issubclass(w.category, ZemaxWarning)]
    assert len(msgs) == 1
    assert msgs[0].startswith(f"{p}:{ln}: glass 'H-ZLAF96' is not in the shipped CDGM "
                              f"catalogue; using the GLAS line's model values n_d 1.959, V_d 17.47")
    assert msgs[0].endswith("--glass-catalog")
    assert nd(lens) == pytest.approx(1.959, abs=1e-12)
    # with the vendor's catalogue the glass is the catalogue's, and the stale line is noted
    cat = agf(tmp_path / "CDGM.agf", {"H-ZLAF96": 2.0998})
    with pytest.warns(ZemaxWarning, match=rf":{ln}: glass 'H-ZLAF96': the GLAS line's n_d 1\.959"):
        real = read_zmx(p, glass_catalogs=[cat])
    assert nd(real) == pytest.approx(2.0998, abs=1e-12)
    # a fallback never overrides a glass that is found
    with pytest.warns(ZemaxWarning):
        also = read_zmx(p, glass_catalogs=[cat], glass_fallback="model")
    assert nd(also) == pytest.approx(2.0998, abs=1e-12)


def test_catalogue_order_gcat_then_user_then_shipped(tmp_path, monkeypatch):
    """A name in more than one place: the file's GCAT catalogues (a user .agf of a GCAT name
    overriding the shipped one of that name), then the user's other catalogues, then a shipped
    catalogue the file does not name."""
    monkeypatch.delenv(GLASS_PATH_ENV, raising=False)
    extra = agf(tmp_path / "EXTRA.agf", {"N-BK7": 1.7, "S-LAH66": 1.8, "ACME-1": 1.65})
    # N-BK7 in the GCAT-named shipped SCHOTT: SCHOTT's, not the unnamed user catalogue's
    lens = read_zmx(write(tmp_path, singlet()), glass_catalogs=[extra])
    assert nd(lens) == pytest.approx(1.5168, abs=2e-5)
    # a user .agf named like the GCAT entry overrides the shipped catalogue of that name
    schott = agf(tmp_path / "SCHOTT.agf", {"N-BK7": 1.6})
    lens = read_zmx(write(tmp_path, singlet()), glass_catalogs=[extra, schott])
    assert nd(lens) == pytest.approx(1.6, abs=1e-12)
    # S-LAH66 is in OHARA (shipped, not named by GCAT SCHOTT): the user catalogue comes first
    s = singlet(glass="GLAS S-LAH66 0 0 1.7725 49.6 0 0 0 0 0 0")
    with pytest.warns(ZemaxWarning, match="using the user catalogue EXTRA"):
        lens = read_zmx(write(tmp_path, s, "u.zmx"), glass_catalogs=[extra])
    assert nd(lens) == pytest.approx(1.8, abs=1e-12)
    with pytest.warns(ZemaxWarning, match="using OHARA"):
        lens = read_zmx(write(tmp_path, s, "u.zmx"))
    assert nd(lens) == pytest.approx(1.7725, abs=5e-5)


def test_the_environment_variable_gives_files_and_folders(tmp_path, monkeypatch):
    folder = tmp_path / "glass"
    folder.mkdir()
    agf(folder / "acme.AGF", {"ACME-1": 1.65})
    one = agf(tmp_path / "OTHER.agf", {"ACME-2": 1.75})
    text = singlet(glass="GLAS ACME-1 0 0 1.65 50 0 0 0 0 0 0", gcat="GCAT ACME")
    p = write(tmp_path, text)
    monkeypatch.delenv(GLASS_PATH_ENV, raising=False)
    with pytest.raises(ZemaxFileError, match=r"\(catalogue ACME\) is not shipped; pass "
                                             r"--glass-catalog ACME\.agf$"):
        read_zmx(p)
    monkeypatch.setenv(GLASS_PATH_ENV, f"{one}{os.pathsep}{folder}")
    assert nd(read_zmx(p)) == pytest.approx(1.65, abs=1e-12)
    q = write(tmp_path, singlet(glass="GLAS ACME-2 0 0 1.75 50 0 0 0 0 0 0", gcat="GCAT OTHER"),
              "q.zmx")
    assert nd(read_zmx(q)) == pytest.approx(1.75, abs=1e-12)
    # a catalogue passed by the caller wins over the variable's of the same name
    (tmp_path / "mine").mkdir()
    mine = agf(tmp_path / "mine" / "ACME.agf", {"ACME-1": 1.66})
    assert nd(read_zmx(p, glass_catalogs=[mine])) == pytest.approx(1.66, abs=1e-12)
    monkeypatch.setenv(GLASS_PATH_ENV, str(tmp_path / "nowhere"))
    with pytest.raises(FileNotFoundError, match=rf"{GLASS_PATH_ENV}: .*nowhere"):
        read_zmx(p)


def run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli_main(argv)
    return rc, out.getvalue(), err.getvalue()


def test_command_line_glass_catalog_and_verbose_details(tmp_path, monkeypatch):
    monkeypatch.delenv(GLASS_PATH_ENV, raising=False)
    text = singlet(glass="GLAS D-ZK3M 0 0 1.601 50.3 0 0 0 0 0 0", gcat="GCAT LIGHTPATH SCHOTT")
    p = write(tmp_path, text)
    ln = line_of(text, "D-ZK3M")
    rc, _, err = run(["report", str(p)])
    assert rc != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].endswith(
        f"t.zmx:{ln}: glass 'D-ZK3M' (catalogue LIGHTPATH) is not shipped; pass --glass-catalog "
        f"LIGHTPATH.agf (-v: details)")
    rc, _, err = run(["report", str(p), "-v"])
    assert rc != 0 and "catalogues searched by exact name: LIGHTPATH" not in err
    assert "catalogues searched by exact name: SCHOTT (current vendor catalogue" in err
    assert "'D-ZK3' (CDGM" in err
    cat = agf(tmp_path / "LIGHTPATH.agf", {"D-ZK3M": 1.601})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        for cmd in (["report", str(p), "--json"],
                    ["plot", str(p), "--kind", "layout", "-o", str(tmp_path / "l.png")]):
            rc, out, err = run([*cmd[:2], "--glass-catalog", str(cat), *cmd[2:]])
            assert rc == 0, err
    rc, _, err = run(["report", "double_gauss", "--glass-catalog", str(cat)])
    assert rc != 0 and "--glass-catalog applies to Zemax files (.zmx) only" in err
