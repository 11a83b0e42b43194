#!/usr/bin/env bash
# Regenerates schemas/generatedSchema.usda and schemas/plugInfo.json from
# schemas/schema.usda with usd-core's usdGenSchema (needs jinja2; both in .venv):
#   scripts/gen-schema.sh [PYTHON]
# The schema is codeless (skipCodeGeneration): no C++ is generated or built. The
# plugInfo.json placeholders that a compiled schema library would fill in at build time
# are set for a resource-only plugin found through PXR_PLUGINPATH_NAME.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
PY=${1:-$ROOT/.venv/bin/python}
[[ "$PY" = /* ]] || PY="$PWD/$PY"   # absolute (not resolved: a venv interpreter is a symlink)
cd "$ROOT/schemas"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
if ! "$PY" -m pxr.Usd.usdGenSchema -q schema.usda . > "$log" 2>&1; then
  cat "$log" >&2
  exit 1
fi
grep -v "is missing. Run usdInitSchema" "$log" || true
sed -i 's|"@PLUG_INFO_LIBRARY_PATH@"|""|; s|"@PLUG_INFO_RESOURCE_PATH@"|"."|; s|"@PLUG_INFO_ROOT@"|"."|' plugInfo.json
if grep -q "@PLUG_INFO" plugInfo.json; then echo "gen-schema: placeholders left in plugInfo.json" >&2; exit 1; fi
