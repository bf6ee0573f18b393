# Sourced by the device scripts (device_closedloop.sh, device_fourgpu.sh) from the repository
# root: the GPU host's environment (scripts/gpu_env.sh, once per machine) in this shell, the
# project's commands on PATH, and with BASE_TAR (carried: `git archive REV $(git diff
# --name-only REV -- drivee2e_data loaders collect) -o out/base_overlay.tar`, the files that
# differ) a base version installed in /tmp/proj_base: `versions` is (base work), else (work).
if [ ! -f /tmp/drivee2e_env ]; then
    bash scripts/gpu_env.sh > /tmp/gpu_env.log 2>&1 || { tail -20 /tmp/gpu_env.log; exit 1; }
fi
# shellcheck disable=SC1091
source /tmp/drivee2e_env
export PATH="/tmp/proj/bin:$PATH"
versions=(work)
if [ -n "${BASE_TAR:-}" ]; then
    # the working tree with the base's versions of the files that differ put back over it
    rm -rf /tmp/base_src && mkdir -p /tmp/base_src && cp -r "$(pwd)/." /tmp/base_src/
    tar -xf "$BASE_TAR" -C /tmp/base_src
    # without the working tree's build folder (left by gpu_env.sh's install): setuptools copies a
    # module into build/lib only when the source is newer, and the tar's files carry their
    # commit's older times, so the "base" installed was this version's code wherever the two
    # differ (found 2026-11-29: both "versions" wrote the same logs)
    rm -rf /tmp/base_src/build /tmp/base_src/*.egg-info
    PYTHONPATH=/tmp/site python3 -m pip install -q --no-deps --no-build-isolation \
        --target /tmp/proj_base /tmp/base_src > /tmp/base_install.log 2>&1
    python3 -m compileall -q /tmp/proj_base > /dev/null || true
    versions=(base work)
fi
