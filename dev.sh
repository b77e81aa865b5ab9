#!/usr/bin/env bash
# deeplens developer entry point.  Usage:
#   bash dev.sh run    # set up (first time) and run the main job
#   bash dev.sh test   # set up (first time) and run the default test suite (2 workers)
#   bash dev.sh lint   # set up (first time) and run ruff (rules in pyproject.toml)
#   bash dev.sh docs   # set up (first time) and build the documentation site (mkdocs, strict)
#   bash dev.sh setup  # set up (first time) only
# Set-up is idempotent: a virtual environment in .venv with `pip install -e .[dev,docs]`.
set -euo pipefail
cd "$(dirname "$0")"
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
stamp=.venv/.deeplens-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[dev,docs]"
    touch "$stamp"
fi
cmd=${1:-test}
shift || true
case "$cmd" in
    setup) exit 0 ;;
    # two worker processes of one torch thread each (pytest-xdist): on 2 cores about half the
    # wall time of one process at two threads; DEEPLENS_TEST_WORKERS=0 (or -n 0) runs serially
    test) export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
          exec .venv/bin/python -m pytest -q -n "${DEEPLENS_TEST_WORKERS:-2}" "$@" ;;
    lint) exec .venv/bin/ruff check deeplens tests "$@" ;;
    # warnings (a broken link, a missing page or docstring reference) are errors
    docs) exec .venv/bin/mkdocs build --strict --site-dir "${DOCS_SITE_DIR:-site}" "$@" ;;
    run)
        # the main job: end-to-end training (default experiment=edof; pass overrides freely)
        case " $* " in
            *" experiment="*) exec .venv/bin/python train.py "$@" ;;
            *) exec .venv/bin/python train.py experiment=edof "$@" ;;
        esac ;;
    *) echo "usage: bash dev.sh run|test|lint|docs|setup [args]" >&2; exit 2 ;;
esac
