#!/usr/bin/env bash
# Generate the Python API reference of the packages graphcal and factors with pdoc into docs/api/
# (HTML, one page per module, from the docstrings). docs/api/ is generated: it is not part of the
# repository, do not commit it. Open docs/api/index.html in a browser.
# pdoc comes with the test extras (bash tools/setup.sh); else: .venv/bin/pip install pdoc
set -euo pipefail
cd "$(dirname "$0")/.."

# graphcal's __init__ lists its public names in __all__, and pdoc then leaves out the subpackages
# it does not list: name them too (graphcal.calibration, graphcal.recording, ...)
subpackages=$(.venv/bin/python -c "import pkgutil, graphcal
print(' '.join(m.name for m in pkgutil.iter_modules(graphcal.__path__, 'graphcal.') if m.ispkg))")

rm -rf docs/api
# shellcheck disable=SC2086  # one word per subpackage
.venv/bin/python -m pdoc --docformat google -o docs/api graphcal $subpackages factors
echo "wrote docs/api/index.html"
