#!/usr/bin/env bash
# run_pytest.sh FILE_OR_DIR [PYTEST ARGS]: one ctest test made of pytest tests,
# run with the project's virtual environment (.venv, made by tools/rekon deps).
# Without it the test is skipped (exit 77, ctest's SKIP_RETURN_CODE), saying why.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
venv="${REKON_VENV:-$root/.venv}"
if [ ! -x "$venv/bin/python" ] || [ ! -f "$venv/.rekon-requirements" ]; then
  echo "SKIPPED: no Python environment at $venv (tools/rekon deps makes it; it needs PyPI)"
  exit 77
fi
export PYTHONDONTWRITEBYTECODE=1
# -p no:cacheprovider: nothing written into the source tree.
exec "$venv/bin/python" -m pytest -q -p no:cacheprovider -rs "$@"
