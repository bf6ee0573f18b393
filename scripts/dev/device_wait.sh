# Sourced by the device scripts' polling calls (`--wait SECONDS`): a run in the background on
# the GPU host writes a log; each device call waits on it until the run is done or the call's
# time is nearly up (a call runs at most 10 minutes), then reports what is there.
# wait_for PATTERN FILE SECONDS: until a line of FILE matches PATTERN (grep), at most SECONDS.
wait_for() {
    local deadline=$(( $(date +%s) + $3 ))
    while [ "$(date +%s)" -lt "$deadline" ] && ! grep -q "$1" "$2" 2>/dev/null; do
        sleep 10
    done
}
