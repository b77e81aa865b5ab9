"""Rebuild an unseen-file set from its ``benchmarks/zmx_*_sources.tsv`` list, byte for byte.

The real ``.zmx`` files of the unseen sets are not committed (most state no licence); each set's
list names, per file, the repository, the path in it and the commit.  This script writes each file
as ``OUT/<file>`` from local git copies of those repositories, so that anyone can re-run
``benchmarks/zmx_corpus.py OUT`` on the very files a published figure came from.

Usage (from the repository root)::

    python benchmarks/zmx_assemble.py benchmarks/zmx_set8_sources.tsv /tmp/corp/set8 \\
        --mirror /path/to/mirrors

``--mirror`` is a folder holding one git repository (bare or not) per source repository, named
``<owner>+<name>`` (with an optional ``repo`` folder inside), e.g. made with
``git clone --bare https://github.com/<owner>/<name> /path/to/mirrors/<owner>+<name>``.  A file
whose repository or commit is missing is listed at the end and the exit status is 1.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path


def read_sources(tsv: Path) -> list[dict[str, str]]:
    """The rows of a sources list: ``file``, ``repository``, ``path``, ``commit`` (``#`` lines skipped)."""
    rows, header = [], None
    for number, line in enumerate(tsv.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        cells = line.split("\t")
        if header is None:
            header = cells
            missing = {"file", "repository", "path", "commit"} - set(header)
            if missing:
                raise SystemExit(f"{tsv}:{number}: header lacks {sorted(missing)}")
            continue
        if len(cells) < len(header):
            raise SystemExit(f"{tsv}:{number}: {len(cells)} columns, expected {len(header)}")
        rows.append(dict(zip(header, cells)))
    return rows


def git_dir(mirror: Path, repository: str) -> Path | None:
    """The git directory of ``owner/name`` under ``mirror``, or ``None``."""
    base = mirror / repository.replace("/", "+")
    for candidate in (base / "repo" / ".git", base / "repo", base / ".git", base):
        if (candidate / "HEAD").is_file() and (candidate / "objects").is_dir():
            return candidate
    return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sources", type=Path, help="a benchmarks/zmx_*_sources.tsv list")
    parser.add_argument("out", type=Path, help="folder to write the files into")
    parser.add_argument("--mirror", type=Path, required=True,
                        help="folder of <owner>+<name> git repositories")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    missing = []
    rows = read_sources(args.sources)
    for row in rows:
        gd = git_dir(args.mirror, row["repository"])
        if gd is None:
            missing.append(f"{row['file']}: no git copy of {row['repository']} under {args.mirror}")
            continue
        done = subprocess.run(["git", f"--git-dir={gd}", "show", f"{row['commit']}:{row['path']}"],
                              capture_output=True)
        if done.returncode:
            missing.append(f"{row['file']}: {row['repository']} {row['commit'][:10]}:{row['path']}: "
                           f"{done.stderr.decode(errors='replace').strip()}")
            continue
        (args.out / row["file"]).write_bytes(done.stdout)
    print(f"{len(rows) - len(missing)} of {len(rows)} files written to {args.out}")
    for line in missing:
        print("  missing:", line)
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
