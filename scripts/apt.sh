# Source this: `apt_install WHAT PACKAGE...` installs Debian packages for an optional part of the
# test suite where the machine allows it (root and apt-get). Waits for the dpkg/apt locks when
# another install holds them (up to 10 minutes), and when apt-get really fails prints apt's own
# last lines, not a guess. Returns 0 when installed, 1 otherwise (the caller decides whether that
# skips its tests or fails the command); `apt_allowed` says whether to try at all.

apt_allowed() {
    [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1
}

_apt_updated=0

# One apt-get call; retried while another process holds a lock ("Could not get lock").
_apt_retry() {
    local log="$1"; shift
    local try
    for try in $(seq 1 40); do
        if DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout=15 "$@" >"$log" 2>&1; then
            return 0
        fi
        grep -qiE "could not get lock|is held by process|unable to acquire" "$log" || return 1
        [ "$try" = 1 ] && echo "  (waiting for another apt/dpkg process to release its lock)"
        sleep 15
    done
    return 1
}

apt_install() {
    local what="$1"; shift
    if ! apt_allowed; then
        echo "$what: not installed (needs root and apt-get); its tests are skipped"
        return 1
    fi
    local log
    log="$(mktemp)"
    if [ "$_apt_updated" = 0 ]; then
        if ! _apt_retry "$log" update -qq; then
            echo "$what: apt-get update failed; apt-get said:"
            tail -n 15 "$log" | sed 's/^/    /'
            rm -f "$log"
            return 1
        fi
        _apt_updated=1
    fi
    if ! _apt_retry "$log" install -y -qq --no-install-recommends "$@"; then
        echo "$what: apt-get install $* failed; apt-get said:"
        tail -n 15 "$log" | sed 's/^/    /'
        rm -f "$log"
        return 1
    fi
    rm -f "$log"
    return 0
}
