#!/usr/bin/env bash
# Run Python inside RESTframe's development environment, creating it on first use.
# The environment lives outside the clone (cached per requirements file), so reruns are quick:
#   tools/dev.sh -m pytest -q tests
#   RESTFRAME_BPY=4.2 tools/dev.sh -m pytest -q tests/blender   # the same tests on Blender 4.2 LTS
#   tools/dev.sh -m restframe_addon render sample_blends/moving_sphere.blend -o out/moving_sphere.png
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
req="$root/tools/requirements-dev.txt"
# RESTFRAME_BPY=4.2 runs against Blender 4.2 LTS instead (its own cached environment)
case "${RESTFRAME_BPY:-}" in
  ""|5.0) ;;
  4.2) req="$root/tools/requirements-bpy42.txt" ;;
  *) echo "restframe: RESTFRAME_BPY must be 4.2 or 5.0 (got '$RESTFRAME_BPY')" >&2; exit 2 ;;
esac
key=$(sha256sum "$req" | cut -c1-12)
venv="${RESTFRAME_VENV:-${XDG_CACHE_HOME:-$HOME/.cache}/restframe/venv-$key}"
if [ ! -f "$venv/.complete" ]; then
  mkdir -p "$(dirname "$venv")"
  # one creator at a time: parallel test runs or sessions share the cache
  exec 9>"$venv.lock"
  flock 9
  if [ ! -f "$venv/.complete" ]; then
    python=$(command -v python3.11 || command -v python3)
    echo "restframe: creating the environment in $venv (once)" >&2
    rm -rf "$venv"
    "$python" -m venv "$venv"
    "$venv/bin/python" -m pip install -q --upgrade pip >&2
    "$venv/bin/python" -m pip install -q -r "$req" >&2
    touch "$venv/.complete"
  fi
  flock -u 9
fi
cd "$root"
exec "$venv/bin/python" "$@"
