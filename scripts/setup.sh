#!/usr/bin/env bash
# Set up everything mcrt needs, installing only what is missing:
#   1. a libLLVM >= 17 for Dr.Jit's LLVM backend  (apt: newest libllvmNN, NN >= 17, e.g. libllvm19)
#   2. a Python >= 3.11 that can create a venv   (apt: python3 python3-venv, or python3.X python3.X-venv)
#   3. .venv in the repo root with `pip install -e ".[test]"` (skipped while pyproject.toml is unchanged)
#   4. a check that Dr.Jit loads a libLLVM >= 17 and that `import mcrt` works;
#   5. headless Chromium and its WebDriver for the report viewer's browser test
#      (apt: chromium chromium-driver); optional: a failure is a warning, not an error.
#
# Usage: `bash scripts/setup.sh` (scripts/demo.sh and scripts/test.sh source this file and call
# mcrt_setup). Safe to rerun. Sourcing it only defines functions and variables; nothing runs.
#
# Environment:
#   DRJIT_LIBLLVM_PATH     libLLVM.so Dr.Jit should load; when set, no libLLVM is installed.
#   MCRT_PYTHON            interpreter to create .venv with (default: first usable python3.13,
#                          3.12, 3.11, python3 on PATH).
#   MCRT_LLVM_SEARCH_DIRS  colon-separated directories to search for libLLVM instead of the system
#                          ones and `ldconfig -p` (meant for testing the detection).
#   MCRT_SKIP_BROWSER=1    do not look for or install Chromium (the browser test then skips).

set -euo pipefail

MCRT_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
MCRT_VENV="$MCRT_ROOT/.venv"
MCRT_STAMP="$MCRT_VENV/.mcrt-setup-stamp"
# Bump to force a reinstall on every machine after changing how packages are installed.
MCRT_SETUP_VERSION=1
MCRT_MIN_PY_MINOR=11     # Python 3.11
MCRT_MIN_LLVM=17         # Debian's libLLVM 14-16 abort on Mitsuba's first kernel.
MCRT_LLVM_FOUND=""       # path of the best libLLVM found on disk, set by ensure_llvm
MCRT_APT_UPDATED=0
MCRT_BROWSER_READY=0     # 1 once ensure_browser found Chromium and chromedriver

log() { printf '[setup] %s\n' "$*" >&2; }
err() { printf '[setup] error: %s\n' "$*" >&2; }

# ---------------------------------------------------------------------------------------------
# Privileges and apt. Small functions so tests can replace them after sourcing this file.

is_root() { [[ "$(id -u)" -eq 0 ]]; }
have_sudo() { command -v sudo >/dev/null 2>&1; }
have_apt() { command -v apt-get >/dev/null 2>&1 && command -v apt-cache >/dev/null 2>&1; }
can_apt() { have_apt && { is_root || have_sudo; }; }

# Run a command as root: directly when we are root (CI containers often lack sudo), else sudo.
as_root() {
    if is_root; then
        "$@"
    elif have_sudo; then
        log "running as root via sudo: $*"
        sudo "$@"
    else
        return 1
    fi
}

# sudo drops most of the environment, so pass the non-interactive flag through `env`.
apt_get() { as_root env DEBIAN_FRONTEND=noninteractive apt-get "$@"; }

apt_update_once() {
    (( MCRT_APT_UPDATED )) && return 0
    log "apt-get update"
    apt_get -q update >&2 || return 1
    MCRT_APT_UPDATED=1
}

# True if apt knows an installable version of the package (fresh images have empty lists).
apt_has_candidate() {
    local cand
    cand="$(apt-cache policy "$1" 2>/dev/null | sed -n 's/^ *Candidate: *//p')"
    [[ -n "$cand" && "$cand" != "(none)" ]]
}

# Install packages, refreshing the package lists first if one is unknown, and once more if the
# install fails (stale lists give 404s).
apt_install() {
    local pkg
    for pkg in "$@"; do
        apt_has_candidate "$pkg" || { apt_update_once || return 1; break; }
    done
    log "apt-get install $*"
    if ! apt_get -q install -y --no-install-recommends "$@" >&2; then
        (( MCRT_APT_UPDATED )) && return 1
        apt_update_once || return 1
        apt_get -q install -y --no-install-recommends "$@" >&2 || return 1
    fi
}

# ---------------------------------------------------------------------------------------------
# Python >= 3.11 with venv support, and .venv

# Prints "3.X" if the interpreter runs and is >= 3.11 (pyenv shims exist but fail for versions
# that are not selected, so running it is the only reliable test).
python_minor() {
    "$1" - "$MCRT_MIN_PY_MINOR" 2>/dev/null <<'EOF'
import sys
major, minor = sys.version_info[:2]
if major != 3 or minor < int(sys.argv[1]):
    sys.exit(1)
print(f"{major}.{minor}")
EOF
}

python_candidates() {
    if [[ -n "${MCRT_PYTHON:-}" ]]; then
        echo "$MCRT_PYTHON"
        return
    fi
    local v
    for v in python3.13 python3.12 python3.11 python3; do
        command -v "$v" 2>/dev/null || true
        [[ -x "/usr/bin/$v" ]] && echo "/usr/bin/$v"   # when a pyenv shim shadows it
    done
    return 0
}

venv_healthy() {
    [[ -x "$MCRT_VENV/bin/python" ]] && python_minor "$MCRT_VENV/bin/python" >/dev/null
}

remove_venv() {
    # Only delete what looks like a venv, never an unrelated directory called .venv.
    if [[ -e "$MCRT_VENV" && ! -f "$MCRT_VENV/pyvenv.cfg" ]]; then
        err "$MCRT_VENV exists but is not a virtual environment; move it away and rerun."
        exit 1
    fi
    rm -rf "$MCRT_VENV"
}

# Try each usable interpreter until one creates .venv. Sets MCRT_PY_NO_VENV to the version of
# an interpreter that is new enough but lacks venv support (Debian without python3.X-venv).
try_create_venv() {
    local py minor errlog
    MCRT_PY_NO_VENV=""
    errlog="$(mktemp)"
    while read -r py; do
        [[ -n "$py" ]] || continue
        minor="$(python_minor "$py")" || continue
        log "creating .venv with $py (Python $minor)"
        if "$py" -m venv "$MCRT_VENV" >"$errlog" 2>&1; then
            rm -f "$errlog"
            return 0
        fi
        log "$py cannot create a venv: $(grep -v '^$' "$errlog" | tail -n 2 | tr '\n' ' ')"
        remove_venv
        MCRT_PY_NO_VENV="${MCRT_PY_NO_VENV:-$minor}"
    done < <(python_candidates | awk '!seen[$0]++')
    rm -f "$errlog"
    return 1
}

# Which apt packages give us a Python >= 3.11 with venv.
python_apt_packages() {
    if [[ -n "$MCRT_PY_NO_VENV" ]]; then
        echo "python$MCRT_PY_NO_VENV-venv"   # Python is there, ensurepip is not
        return
    fi
    apt_has_candidate python3 || apt_update_once || return 1
    local cand v
    cand="$(apt-cache policy python3 2>/dev/null | sed -n 's/^ *Candidate: *//p')"
    if [[ "$cand" =~ ^3\.([0-9]+) ]] && (( BASH_REMATCH[1] >= MCRT_MIN_PY_MINOR )); then
        echo "python3 python3-venv"           # Debian 12, Ubuntu 24.04
        return
    fi
    for v in 3.13 3.12 3.11; do              # older Ubuntu: python3 is 3.10, python3.11 exists
        if apt_has_candidate "python$v"; then
            echo "python$v python$v-venv"
            return
        fi
    done
    return 1
}

ensure_venv() {
    if venv_healthy; then
        return 0
    fi
    if [[ -n "${MCRT_PYTHON:-}" ]] && ! python_minor "$MCRT_PYTHON" >/dev/null; then
        err "MCRT_PYTHON=$MCRT_PYTHON is not a working Python >= 3.$MCRT_MIN_PY_MINOR; unset it or fix it."
        exit 1
    fi
    if [[ -e "$MCRT_VENV" ]]; then
        log ".venv is broken or too old; recreating it"
        remove_venv
    fi
    try_create_venv && return 0

    local pkgs=""
    if can_apt; then
        pkgs="$(python_apt_packages)" || pkgs=""
    fi
    if [[ -z "$pkgs" ]]; then
        err "no Python >= 3.$MCRT_MIN_PY_MINOR with venv support found and it cannot be installed here."
        err "install one (Debian/Ubuntu: apt-get install python3 python3-venv, or python3.11 python3.11-venv),"
        err "or point MCRT_PYTHON at one, then rerun."
        exit 1
    fi
    # shellcheck disable=SC2086  # $pkgs is a space-separated list of package names
    if ! apt_install $pkgs; then
        err "could not install $pkgs; install it as root and rerun."
        exit 1
    fi
    try_create_venv && return 0
    err "installed $pkgs but still cannot create a venv; set MCRT_PYTHON to a Python >= 3.$MCRT_MIN_PY_MINOR."
    exit 1
}

# pip install -e ".[test]" unless nothing relevant changed since the last successful install.
ensure_packages() {
    local want
    want="$(cat "$MCRT_ROOT/pyproject.toml" <(echo "setup=$MCRT_SETUP_VERSION") \
            <("$MCRT_VENV/bin/python" -c 'import sys; print(sys.version)') | sha256sum | cut -d' ' -f1)"
    if [[ -f "$MCRT_STAMP" && "$(cat "$MCRT_STAMP")" == "$want" ]]; then
        log "Python packages up to date (pyproject.toml unchanged)"
        return 0
    fi
    if [[ -f "$MCRT_STAMP" ]]; then
        log "pyproject.toml changed: pip install -e \".[test]\" into .venv"
    else
        log "pip install -e \".[test]\" into .venv (first run: downloads Mitsuba, Dr.Jit, SciPy, ...)"
    fi
    rm -f "$MCRT_STAMP"
    if ! (cd "$MCRT_ROOT" && "$MCRT_VENV/bin/python" -m pip install -e ".[test]") >&2; then
        err "pip install failed (see above); fix it and rerun."
        exit 1
    fi
    echo "$want" >"$MCRT_STAMP"
}

# Byte-compile mcrt/: an editable install leaves the package as sources, and where
# PYTHONDONTWRITEBYTECODE is set (as in many container images) Python would compile every
# module again at each start, ~0.13 s of every mcrt command on a 2-core machine. Only stale
# or missing .pyc files are written, so a rerun costs a moment.
compile_bytecode() {
    if ! "$MCRT_VENV/bin/python" -m compileall -q "$MCRT_ROOT/mcrt" >/dev/null; then
        log "warning: could not byte-compile mcrt/ (commands start slower; nothing else changes)"
    fi
}

# ---------------------------------------------------------------------------------------------
# libLLVM >= 17

# Print the major version encoded in a libLLVM file name, or nothing if it has none:
#   libLLVM-15.so, libLLVM-14.0.6.so.1, libLLVM.so.19.1, llvm-14/lib/libLLVM.so (via symlink/dir)
llvm_major_from_path() {
    local path="$1" base target
    base="${path##*/}"
    if [[ "$base" =~ ^libLLVM-([0-9]+) ]] || [[ "$base" =~ ^libLLVM\.so\.([0-9]+) ]]; then
        echo "${BASH_REMATCH[1]}"
    elif [[ "$base" == libLLVM.so ]]; then
        target="$(readlink -f "$path" 2>/dev/null || true)"
        if [[ -n "$target" && "${target##*/}" != libLLVM.so ]]; then
            llvm_major_from_path "$target"
        elif [[ "$path" =~ /llvm-([0-9]+)/ ]]; then
            echo "${BASH_REMATCH[1]}"
        fi
    fi
}

llvm_search_dirs() {
    if [[ -n "${MCRT_LLVM_SEARCH_DIRS:-}" ]]; then
        tr ':' '\n' <<<"$MCRT_LLVM_SEARCH_DIRS"
        return
    fi
    # Dr.Jit dlopen()s "libLLVM.so" (honours LD_LIBRARY_PATH), then globs the multiarch dirs.
    [[ -n "${LD_LIBRARY_PATH:-}" ]] && tr ':' '\n' <<<"$LD_LIBRARY_PATH"
    local d
    for d in /usr/lib/*-linux-gnu /lib/*-linux-gnu /usr/lib/wsl/lib /usr/lib/llvm-*/lib \
             /usr/lib64 /usr/local/lib; do
        [[ -d "$d" ]] && echo "$d"
    done
    return 0
}

# Every libLLVM shared library we can see, one path per line.
llvm_candidates() {
    local d f ldconfig
    while read -r d; do
        [[ -n "$d" ]] || continue
        for f in "$d"/libLLVM-*.so* "$d"/libLLVM.so*; do
            [[ -e "$f" ]] && echo "$f"
        done
    done < <(llvm_search_dirs)
    if [[ -z "${MCRT_LLVM_SEARCH_DIRS:-}" ]]; then
        # /sbin is not on a normal user's PATH on Debian.
        ldconfig="$(command -v ldconfig || echo /sbin/ldconfig)"
        "$ldconfig" -p 2>/dev/null | sed -n 's/^[[:space:]]*libLLVM[-.][^ ]* .*=> //p' || true
    fi
}

# Scan for libLLVM and set MCRT_LLVM_BEST_MAJOR / MCRT_LLVM_BEST_PATH (newest found, major -1 if
# none) and MCRT_LLVM_SEEN (all majors found, for messages). No subshell, so the globals stick.
scan_llvm() {
    local path major
    MCRT_LLVM_BEST_MAJOR=-1
    MCRT_LLVM_BEST_PATH=""
    MCRT_LLVM_SEEN=""
    while read -r path; do
        major="$(llvm_major_from_path "$path")"
        [[ -n "$major" ]] || continue
        [[ " $MCRT_LLVM_SEEN " == *" $major "* ]] || MCRT_LLVM_SEEN="${MCRT_LLVM_SEEN:+$MCRT_LLVM_SEEN }$major"
        if (( major > MCRT_LLVM_BEST_MAJOR )); then
            MCRT_LLVM_BEST_MAJOR="$major"
            MCRT_LLVM_BEST_PATH="$path"
        fi
    done < <(llvm_candidates)
    return 0
}

# Newest libllvmNN package with NN >= 17 that apt can install (e.g. libllvm19 on Debian 12).
llvm_apt_package() {
    apt-cache search --names-only '^libllvm[0-9]+$' 2>/dev/null \
        | sed -n 's/^libllvm\([0-9][0-9]*\) .*/\1/p' | sort -n \
        | awk -v min="$MCRT_MIN_LLVM" '$1 >= min { last = $1 } END { if (last) print "libllvm" last }'
}

die_no_llvm() {
    err "$1"
    err "Dr.Jit's LLVM backend needs libLLVM >= $MCRT_MIN_LLVM (libLLVM 14-16 crash on the first kernel)."
    [[ -v MCRT_LLVM_SEEN ]] && err "libLLVM versions found on disk: ${MCRT_LLVM_SEEN:-none}."
    err "Fix: as root run 'apt-get install libllvm19' (or any libllvmNN with NN >= $MCRT_MIN_LLVM, e.g. from"
    err "     apt.llvm.org), or set DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so of version >= $MCRT_MIN_LLVM; then rerun."
    exit 1
}

# True if a libLLVM >= 17 is on disk; its path goes to MCRT_LLVM_FOUND.
find_usable_llvm() {
    MCRT_LLVM_FOUND=""
    scan_llvm
    (( MCRT_LLVM_BEST_MAJOR >= MCRT_MIN_LLVM )) || return 1
    MCRT_LLVM_FOUND="$MCRT_LLVM_BEST_PATH"
    log "libLLVM $MCRT_LLVM_BEST_MAJOR found: $MCRT_LLVM_FOUND"
}

ensure_llvm() {
    local user_path="${DRJIT_LIBLLVM_PATH:-}" major pkg
    if [[ -n "$user_path" ]]; then
        # The user's explicit choice wins; only catch the obvious mistakes early.
        if [[ "$user_path" == */* && ! -e "$user_path" ]]; then
            err "DRJIT_LIBLLVM_PATH=$user_path does not exist; unset it or point it at libLLVM >= $MCRT_MIN_LLVM."
            exit 1
        fi
        major="$(llvm_major_from_path "$user_path")"
        if [[ -n "$major" ]] && (( major < MCRT_MIN_LLVM )); then
            err "DRJIT_LIBLLVM_PATH=$user_path is libLLVM $major; Dr.Jit needs >= $MCRT_MIN_LLVM."
            err "Unset it or point it at a newer libLLVM (Debian 12: apt-get install libllvm19)."
            exit 1
        fi
        log "libLLVM: using DRJIT_LIBLLVM_PATH=$user_path"
        return 0
    fi

    find_usable_llvm && return 0
    log "no libLLVM >= $MCRT_MIN_LLVM found (found: ${MCRT_LLVM_SEEN:-none}); installing one with apt"
    can_apt || die_no_llvm "cannot install libLLVM: need apt-get and root or sudo."
    pkg="$(llvm_apt_package)"
    if [[ -z "$pkg" ]]; then
        apt_update_once || die_no_llvm "apt-get update failed."
        pkg="$(llvm_apt_package)"
    fi
    [[ -n "$pkg" ]] || die_no_llvm "apt offers no libllvmNN package with NN >= $MCRT_MIN_LLVM."
    apt_install "$pkg" || die_no_llvm "apt-get install $pkg failed."
    find_usable_llvm || die_no_llvm "installed $pkg but found no libLLVM >= $MCRT_MIN_LLVM afterwards."
}

# ---------------------------------------------------------------------------------------------
# Final check, without compiling a kernel (an old libLLVM aborts the process on the first one).

# Print the libLLVM version Dr.Jit loads ("none" if it finds none) and succeed if it is new
# enough; print "import-error" if drjit cannot be imported at all.
drjit_llvm_check() {
    "$MCRT_VENV/bin/python" - "$MCRT_MIN_LLVM" <<'EOF'
import sys
try:
    import drjit as dr
except Exception as e:
    print("import-error")
    print(f"[setup] import drjit: {type(e).__name__}: {e}", file=sys.stderr)
    sys.exit(1)
if not dr.has_backend(dr.JitBackend.LLVM):
    print("none")
    sys.exit(1)
major, minor, patch = dr.detail.llvm_version()
print(f"{major}.{minor}.{patch}")
sys.exit(0 if major >= int(sys.argv[1]) else 1)
EOF
}

verify() {
    local loaded ok=0
    loaded="$(drjit_llvm_check)" && ok=1
    if [[ "$loaded" == import-error ]]; then
        err "drjit cannot be imported from .venv; delete .venv and rerun."
        exit 1
    fi
    # Dr.Jit prefers a plain "libLLVM.so" on the loader path over the newest versioned file, so
    # it can load an old library although a new one is installed: then point it at ours.
    if (( !ok )) && [[ -z "${DRJIT_LIBLLVM_PATH:-}" && -n "$MCRT_LLVM_FOUND" ]]; then
        log "Dr.Jit loaded libLLVM $loaded; retrying with DRJIT_LIBLLVM_PATH=$MCRT_LLVM_FOUND"
        export DRJIT_LIBLLVM_PATH="$MCRT_LLVM_FOUND"
        if loaded="$(drjit_llvm_check)"; then
            ok=1
            log "note: export DRJIT_LIBLLVM_PATH=$MCRT_LLVM_FOUND to run mcrt outside these scripts"
        else
            unset DRJIT_LIBLLVM_PATH
        fi
    fi
    (( ok )) || die_no_llvm "Dr.Jit's LLVM backend is unusable: it loaded libLLVM $loaded${DRJIT_LIBLLVM_PATH:+ (DRJIT_LIBLLVM_PATH=$DRJIT_LIBLLVM_PATH)}."
    if ! (cd "$MCRT_ROOT" && "$MCRT_VENV/bin/python" -c 'import mcrt'); then
        err "'import mcrt' failed (see above)."
        exit 1
    fi
    log "ready: Python $("$MCRT_VENV/bin/python" -c 'import platform; print(platform.python_version())') in .venv, Dr.Jit uses libLLVM $loaded"
}

# ---------------------------------------------------------------------------------------------
# Headless Chromium + chromedriver (tests/analysis/test_report_viewer.py drives the report in it)

# A Chromium-family browser and a chromedriver on this machine (Debian: /usr/bin/chromium and
# /usr/bin/chromedriver; GitHub's Ubuntu images: google-chrome and $CHROMEWEBDRIVER).
have_browser() {
    local b d found_b="" found_d=""
    for b in chromium chromium-browser google-chrome google-chrome-stable; do
        command -v "$b" >/dev/null 2>&1 && { found_b="$b"; break; }
    done
    for d in chromedriver "${CHROMEWEBDRIVER:+$CHROMEWEBDRIVER/chromedriver}"; do
        [[ -n "$d" ]] && command -v "$d" >/dev/null 2>&1 && { found_d="$d"; break; }
    done
    [[ -n "$found_b" && -n "$found_d" ]] || return 1
    log "browser for the report test: $found_b with $found_d"
}

ensure_browser() {
    if [[ "${MCRT_SKIP_BROWSER:-0}" == 1 ]]; then
        log "MCRT_SKIP_BROWSER=1: not looking for Chromium (the report viewer's browser test skips)"
        return 0
    fi
    if have_browser; then
        MCRT_BROWSER_READY=1
        return 0
    fi
    if can_apt && apt_install chromium chromium-driver && have_browser; then
        MCRT_BROWSER_READY=1
        return 0
    fi
    log "warning: no headless Chromium with chromedriver (Debian: apt-get install chromium"
    log "         chromium-driver); mcrt works without it, the report viewer's browser test skips."
}

mcrt_setup() {
    ensure_llvm
    ensure_venv
    ensure_packages
    compile_bytecode
    verify
    ensure_browser
}

# Run only when executed (`bash scripts/setup.sh`), not when sourced by demo.sh / test.sh.
if [[ "${BASH_SOURCE[0]}" == "$0" ]]; then
    mcrt_setup
    log "activate with: source .venv/bin/activate   (or run .venv/bin/mcrt directly)"
fi
