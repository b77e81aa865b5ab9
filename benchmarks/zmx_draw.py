"""Draw a new unseen set of real ``.zmx`` files by a written rule (see ``benchmarks/zmx_set9_rule.md``).

Walks the ``.zmx`` files (any case) of the given git repositories at the given commits, each
repository's files in order of the SHA-1 of their path (hex of the UTF-8 path), skips every
``repository``/``path`` pair an earlier sources list names, and drops a file that is

1. non-sequential or mixed-mode (``MODE NSC``, or a ``NONSEQCO`` surface);
2. multi-configuration (``MNUM n`` with n > 1);
3. encrypted, a ``BLACKBOX``, or no ``.zmx`` text (no ``SURF`` line);
4. a duplicate: its surface list (``CURV`` and ``DISZ`` of every ``SURF``, as floats) equals that of a
   file under one of the ``--against`` folders or of a file drawn before it.

Nothing else is dropped.  Each drawn file is written byte for byte to ``OUT/<prefix>_<name>.zmx``
and listed (tab-separated, the columns of the other lists) on standard output; each dropped file
is listed with its reason on standard error.

Usage::

    python benchmarks/zmx_draw.py OUT --source PREFIX OWNER/NAME GITDIR COMMIT [--cap N] ... \\
        --seen benchmarks/zmx_*_sources.tsv --against tests/data/zmx_real /tmp/corp/set8 ...
"""

from __future__ import annotations

import argparse
import hashlib
import re
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.zmx_assemble import read_sources  # noqa: E402
from deeplens.optics.io.agf import decode_zemax_text  # noqa: E402


def surface_list(text: str) -> tuple:
    """``(CURV, DISZ)`` of every ``SURF`` block, as floats (``INFINITY`` is inf)."""
    out, curv, disz, inside = [], None, None, False
    for line in text.splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] == "SURF":
            if inside:
                out.append((curv, disz))
            inside, curv, disz = True, None, None
        elif inside and words[0] == "CURV" and len(words) > 1:
            curv = float(words[1])
        elif inside and words[0] == "DISZ" and len(words) > 1:
            disz = float("inf") if words[1].upper() == "INFINITY" else float(words[1])
    if inside:
        out.append((curv, disz))
    return tuple(out)


def drop_reason(text: str) -> str | None:
    """Why a file is dropped by rules 1-3, or ``None``."""
    if "SURF" not in text:
        return "no .zmx text (encrypted or not a .zmx)"
    if re.search(r"^MODE\s+NSC", text, re.M) or re.search(r"^\s*TYPE\s+NONSEQCO", text, re.M):
        return "non-sequential or mixed-mode"
    m = re.search(r"^MNUM\s+(\d+)", text, re.M)
    if m and int(m.group(1)) > 1:
        return f"MNUM {m.group(1)}"
    if re.search(r"^\s*TYPE\s+BLACKBOX", text, re.M):
        return "BLACKBOX"
    return None


def decode(data: bytes) -> str:
    with tempfile.NamedTemporaryFile(suffix=".zmx") as tmp:
        tmp.write(data)
        tmp.flush()
        return decode_zemax_text(Path(tmp.name))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--source", nargs=4, action="append", required=True,
                        metavar=("PREFIX", "REPOSITORY", "GITDIR", "COMMIT"))
    parser.add_argument("--cap", type=int, action="append", default=[],
                        help="at most this many files of the n-th --source (0: no cap)")
    parser.add_argument("--licence", action="append", default=[])
    parser.add_argument("--seen", type=Path, nargs="*", default=[])
    parser.add_argument("--against", type=Path, nargs="*", default=[])
    args = parser.parse_args(argv)
    seen = {(r["repository"], r["path"]) for tsv in args.seen for r in read_sources(tsv)}
    known = {}
    for folder in args.against:
        for f in sorted(folder.glob("*")):
            if f.suffix.lower() == ".zmx":
                known.setdefault(surface_list(decode(f.read_bytes())), f"{folder.name}/{f.name}")
    if args.out.exists() and any(args.out.iterdir()):
        parser.error(f"{args.out} is not empty: a draw writes into an empty folder, so that "
                     f"it can be repeated")
    args.out.mkdir(parents=True, exist_ok=True)
    print("file\trepository\tpath\tcommit\tlicence")
    for i, (prefix, repository, gitdir, commit) in enumerate(args.source):
        cap = args.cap[i] if i < len(args.cap) else 0
        licence = args.licence[i] if i < len(args.licence) else "none stated"
        names = subprocess.run(["git", f"--git-dir={gitdir}", "ls-tree", "-r", "--name-only", commit],
                               capture_output=True, check=True, text=True).stdout.splitlines()
        paths = sorted((p for p in names if p.lower().endswith(".zmx")),
                       key=lambda p: hashlib.sha1(p.encode("utf-8")).hexdigest())
        drawn = 0
        for path in paths:
            if cap and drawn >= cap:
                break
            if (repository, path) in seen:
                continue
            data = subprocess.run(["git", f"--git-dir={gitdir}", "show", f"{commit}:{path}"],
                                  capture_output=True, check=True).stdout
            text = decode(data)
            why = drop_reason(text)
            key = surface_list(text) if why is None else None
            if why is None and key in known:
                why = f"duplicate of {known[key]}"
            if why:
                print(f"dropped\t{repository}\t{path}\t{why}", file=sys.stderr)
                continue
            stem = re.sub(r"[^A-Za-z0-9-]+", "_", Path(path).stem)
            name = f"{prefix}_{stem}.zmx"
            while (args.out / name).exists():   # two paths with one base name
                name = name[:-4] + "_.zmx"
            (args.out / name).write_bytes(data)
            known[key] = f"{args.out.name}/{name}"
            drawn += 1
            print(f"{name}\t{repository}\t{path}\t{commit}\t{licence}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
