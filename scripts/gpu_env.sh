#!/usr/bin/env bash
# The GPU host's environment for the benchmarks, on a machine without network access whose
# python3 already holds numpy, torch, OpenCV, pyarrow and tqdm (docs/benchmarks.md, "How the
# GPU environment was made"). Run from the repository root with these folders beside it:
#   .gl/   Debian's GL loader packages (libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
#   .whl/  Python 3.12 wheels: mcap, mcap-protobuf-support, foxglove-schemas-protobuf, shapely,
#          pyproj, lz4, zstandard, moderngl, glcontext; torchmetrics and lightning-utilities (train,
#          predict, openloop)
#   .pb/   the pybullet 3.2.7 sdist with examples/pybullet/gym/{pybullet_data,pybullet_envs}
#          removed (pybullet-3.2.7.tar.gz)
# Then: source /tmp/drivee2e_env (PYTHONPATH and NVIDIA's EGL vendor file) and run the scripts
# from outside the checkout.
set -euo pipefail
repo=$(pwd)
for deb in .gl/*.deb; do dpkg -x "$deb" /; done
ldconfig
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl
if [ ! -d /tmp/build/pybullet-3.2.7/build ]; then  # built once per machine (about a minute)
    mkdir -p /tmp/build && tar -xzf .pb/pybullet-3.2.7.tar.gz -C /tmp/build
    (cd /tmp/build/pybullet-3.2.7 && python3 setup.py build_ext --inplace >/tmp/build/log 2>&1)
fi
# both extensions: pybullet alone quietly falls back to TinyRenderer
find /tmp/build/pybullet-3.2.7/build -name "pybullet*.so" -o -name "eglRenderer*.so" \
    | xargs -I{} cp {} /tmp/site/
rm -rf "$repo/build"  # setuptools would keep a module of an earlier build that is newer than its source
PYTHONPATH=/tmp/site python3 -m pip install -q --no-deps --no-build-isolation --target /tmp/proj "$repo"
# byte-compiled as a pip install leaves them: else each of sixteen workers compiles the modules
# it imports after its fork (0.12 s of a worker's first set-up on an H100 host)
python3 -m compileall -q /tmp/site /tmp/proj >/dev/null || true
cat >/tmp/drivee2e_env <<EOF
export PYTHONPATH=/tmp/proj:/tmp/site
export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
EOF
