#!/usr/bin/env bash
# Fetch the ONNX Runtime shared library (1.31.1, CPU) from the onnxruntime Python wheel
# into ./.ort/ so the `ort` crate (load-dynamic) can open it. Idempotent: does nothing when
# the library is already there. Uses only pip (the package registry), nothing else.
set -euo pipefail

ORT_VERSION="1.31.1"
LIB="libonnxruntime.so.${ORT_VERSION}"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DEST="${ORT_DEST:-$ROOT/.ort}"

if [[ -s "$DEST/$LIB" ]]; then
  echo "setup-ort: $DEST/$LIB already present"
  exit 0
fi

PY="${PYTHON:-python3}"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT

echo "setup-ort: downloading onnxruntime==$ORT_VERSION wheel (no dependencies)"
"$PY" -m pip download --quiet --no-deps --only-binary=:all: \
  --platform manylinux_2_27_x86_64 --platform manylinux_2_28_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
  --python-version "$("$PY" -c 'import sys; print(f"{sys.version_info[0]}{sys.version_info[1]}")')" \
  -d "$TMP" "onnxruntime==$ORT_VERSION"

WHEEL="$(ls "$TMP"/onnxruntime-"$ORT_VERSION"-*.whl | head -n1)"
mkdir -p "$DEST"
"$PY" - "$WHEEL" "$DEST" "$LIB" <<'PYEOF'
import sys, zipfile, shutil, os
wheel, dest, lib = sys.argv[1:4]
member = "onnxruntime/capi/" + lib
with zipfile.ZipFile(wheel) as z, z.open(member) as src, open(os.path.join(dest, lib + ".part"), "wb") as out:
    shutil.copyfileobj(src, out)
os.replace(os.path.join(dest, lib + ".part"), os.path.join(dest, lib))
PYEOF
echo "setup-ort: installed $DEST/$LIB"
