#!/usr/bin/env bash
# Copies the web console's front-end dependency (uPlot, pinned in package.json, installed by
# `make node`) from node_modules into the package, so that the console works offline and
# `make demo` needs no node.  The copies are generated: never edit them; run this after changing
# uPlot's version in package.json, and commit the result.  tests/test_web.py checks that the
# committed copies are byte-identical to node_modules' (and fails with this script's name).
set -euo pipefail
cd "$(dirname "$0")/.."
src=node_modules/uplot
dst=src/missing_link/publishers/web_static
if [ ! -d "$src" ]; then
    echo "build-web: $src is missing: run make node first" >&2
    exit 1
fi
cp "$src/dist/uPlot.iife.min.js" "$dst/uPlot.iife.min.js"
cp "$src/dist/uPlot.min.css" "$dst/uPlot.min.css"
cp "$src/LICENSE" "$dst/uPlot.LICENSE.txt"
echo "build-web: uPlot $(node -p "require('./$src/package.json').version" 2>/dev/null || echo '?') copied into $dst"
