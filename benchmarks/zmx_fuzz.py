#!/usr/bin/env python
"""Fuzz the Zemax reader with damaged copies of the real-file corpus and count the outcomes.

Each real file of ``tests/data/zmx_real`` and ``tests/data/zmx_opticstudio`` is damaged in
these ways (seeded, ``--per-kind`` of each random kind per file):

* ``truncate``: cut after a random line (a download stopped mid-way);
* ``number``: one number on a random data line replaced by ``nan``, ``inf``, ``-inf``,
  ``1e308``, ``-1e308``, ``1e29`` or ``0``;
* ``duplicate``: a random ``SURF`` block written twice;
* ``encoding``: the whole file as UTF-16 LE or BE without byte-order mark, UTF-16 with one,
  and Latin-1 (these must load as the original does).

Each damaged file is read by ``load_lens`` in a worker process (``--timeout`` seconds each) and
its paraxial EFL, BFL and entrance pupil computed; the outcome is one of

* ``ok``: loaded, and every first-order number finite (or the original's own non-finite one);
* ``error``: refused with deeplens' own error (``LensFileError``/``ZemaxFileError``,
  ``LensError``, ``AgfError``, ``ConfigError``), message naming the file or a line;
* ``unlocated``: refused with deeplens' own error but no file or line in the message;
* ``traceback``: any other exception (a defect: the user sees a raw traceback);
* ``hang``: no answer within the timeout (a defect);
* ``nonsense``: loaded without a warning, but a first-order number is NaN or infinite where
  the original's is finite, or a file cut off or with a block written twice reads with other
  first-order numbers than the original (a defect: a wrong result without an error; a cut
  after the image surface's data reads the same lens and is ``ok``); an encoding that reads
  otherwise than the original.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/zmx_fuzz.py [--per-kind 4] [--seed 0] [--timeout 60]

It prints a table of outcomes per kind and lists every defect with the mutation that made it.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import random
import re
import sys
import tempfile
import time
import warnings
from collections import Counter, defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CORPORA = [REPO / "tests" / "data" / "zmx_real", REPO / "tests" / "data" / "zmx_opticstudio"]
NUMBERS = ("nan", "inf", "-inf", "1e308", "-1e308", "1e29", "0")
NUM = re.compile(r"(?<![\w.])[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?(?![\w.])")


def read_text(path: Path) -> str:
    raw = path.read_bytes()
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return raw.decode("utf-16")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def mutants(text: str, rng: random.Random, per_kind: int):
    """``(kind, description, bytes)`` of the damaged copies of one file."""
    lines = text.splitlines(keepends=True)
    for _ in range(per_kind):
        k = rng.randrange(1, len(lines))
        yield "truncate", f"cut after line {k}", "".join(lines[:k]).encode()
    data = [i for i, ln in enumerate(lines) if NUM.search(ln) and ln.strip()[:4].isupper()]
    for _ in range(per_kind):
        i = rng.choice(data)
        spans = [m.span() for m in NUM.finditer(lines[i])]
        a, b = rng.choice(spans)
        new = rng.choice(NUMBERS)
        ln = lines[i][:a] + new + lines[i][b:]
        out = lines[:i] + [ln] + lines[i + 1:]
        yield "number", f"line {i + 1}: {lines[i].strip()!r} -> {ln.strip()!r}", \
            "".join(out).encode()
    surf = [i for i, ln in enumerate(lines) if ln.startswith("SURF ")]
    for _ in range(min(per_kind, len(surf))):
        j = rng.randrange(len(surf))
        end = surf[j + 1] if j + 1 < len(surf) else len(lines)
        block = lines[surf[j]:end]
        out = lines[:end] + block + lines[end:]
        yield "duplicate", f"SURF block at line {surf[j] + 1} twice", "".join(out).encode()
    yield "encoding", "UTF-16 LE, no BOM", text.encode("utf-16-le")
    yield "encoding", "UTF-16 BE, no BOM", text.encode("utf-16-be")
    yield "encoding", "UTF-16 with BOM", text.encode("utf-16")
    yield "encoding", "Latin-1", text.encode("latin-1", errors="replace")


def _first_order(path: str):
    """``(status, detail, numbers, warned)`` of reading one file (in the worker)."""
    import torch  # noqa: F401

    from deeplens.optics.errors import ConfigError, LensError, LensFileError
    from deeplens.optics.io import load_lens
    from deeplens.optics.io.agf import AgfError
    from deeplens.optics.paraxial import paraxial

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        try:
            lens = load_lens(path)
            p = paraxial(lens)
            nums = [float(p.efl), float(p.bfl), float(p.entrance_pupil_diameter)]
        except (LensFileError, LensError, AgfError, ConfigError) as e:
            msg = str(e)
            located = Path(path).name in msg or re.search(r"\bline \d+|:\d+:", msg)
            return ("error" if located else "unlocated"), msg[:300], None, bool(seen)
        except Exception as e:  # noqa: BLE001  (what the fuzz is for)
            return "traceback", f"{type(e).__name__}: {str(e)[:300]}", None, bool(seen)
    return "ok", "", nums, bool(seen)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--per-kind", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--limit", type=int, default=None, help="first N files only")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    files = sorted(p for c in CORPORA for p in c.glob("*.zmx"))[:args.limit]
    ctx = mp.get_context("spawn")
    pool = ctx.Pool(1)
    counts = defaultdict(Counter)
    defects = []
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        for f in files:
            text = read_text(f)
            base = pool.apply_async(_first_order, (str(f),)).get(args.timeout)
            base_nums = base[2]
            for n, (kind, what, data) in enumerate(mutants(text, rng, args.per_kind)):
                # the file's own name, so that messages naming it count as located
                d = Path(tmp) / f"{f.stem}-{n}"
                d.mkdir()
                p = d / f.name
                p.write_bytes(data)
                for agf in f.parent.glob("*.agf"):
                    (d / agf.name).write_bytes(agf.read_bytes())
                try:
                    status, detail, nums, warned = pool.apply_async(
                        _first_order, (str(p),)).get(args.timeout)
                except mp.TimeoutError:
                    pool.terminate()
                    pool = ctx.Pool(1)
                    status, detail, nums, warned = "hang", f"> {args.timeout} s", None, False
                if status == "ok" and base_nums is not None and not warned and any(
                        not math.isfinite(v) and math.isfinite(b)
                        for v, b in zip(nums, base_nums)):
                    status, detail = "nonsense", f"first order {nums} (original {base_nums})"
                if status == "ok" and kind in ("truncate", "duplicate") and not warned and (
                        base_nums is None or any(abs(v - b) > 1e-9 * max(abs(b), 1.0)
                                                 for v, b in zip(nums, base_nums))):
                    status, detail = "nonsense", (f"read as another lens without a warning: "
                                                  f"first order {nums} (original {base_nums})")
                if kind == "encoding" and status != base[0]:
                    status, detail = "nonsense" if status == "ok" else status, \
                        f"{detail} (the original reads as {base[0]})"
                counts[kind][status] += 1
                if status in ("traceback", "hang", "nonsense", "unlocated"):
                    defects.append((f.name, kind, what, status, detail))
    pool.terminate()
    statuses = ("ok", "error", "unlocated", "traceback", "hang", "nonsense")
    print(f"{len(files)} files, {sum(sum(c.values()) for c in counts.values())} damaged copies, "
          f"{time.time() - t0:.0f} s, seed {args.seed}\n")
    print("| kind | " + " | ".join(statuses) + " |")
    print("|---|" + "---|" * len(statuses))
    for kind, c in counts.items():
        print(f"| {kind} | " + " | ".join(str(c[s]) for s in statuses) + " |")
    tot = Counter()
    for c in counts.values():
        tot.update(c)
    print("| all | " + " | ".join(str(tot[s]) for s in statuses) + " |")
    if defects:
        print("\nDefects:")
        for d in defects:
            print("- " + " | ".join(d))
    return 1 if any(tot[s] for s in ("traceback", "hang", "nonsense")) else 0


if __name__ == "__main__":
    sys.exit(main())
