#!/usr/bin/env bash
# Install, upgrade or remove the cablecal daemon on a cell PC (systemd, udev).
#
#   sudo deploy/install.sh                 install or upgrade from this source tree
#   sudo deploy/install.sh --uninstall     stop and remove; keep database and configuration
#   sudo deploy/install.sh --purge         also remove /var/lib/cablecal, /etc/cablecal, user
#   deploy/install.sh --destdir DIR [--no-pip] [--uninstall|--purge]
#                                          lay the files out under DIR (a test root); user,
#                                          systemctl and udevadm commands are printed, not run
#
# What an install does (every step is idempotent, so running it again upgrades):
#   - system user and group cablecal (no login shell), member of dialout (serial ports);
#   - venv /opt/cablecal/venv with this project pip-installed into it (not editable: the
#     service must not depend on the checkout, which ProtectHome= may hide anyway);
#   - /etc/systemd/system/cablecal.service and /etc/udev/rules.d/99-cablecal.rules;
#   - /etc/cablecal/cablecal.toml from the example, only if there is none (an upgrade keeps
#     the configuration; the current example is always refreshed as cablecal.toml.example);
#   - /etc/cablecal/env with a random CABLECAL_API_TOKEN, only if there is none;
#   - systemctl daemon-reload, udev reload and trigger, enable and (re)start the service.
# It never touches /var/lib/cablecal (the database), except --purge.
set -euo pipefail

readonly SERVICE=cablecal.service
readonly SERVICE_USER=cablecal
readonly APP_DIR=/opt/cablecal
readonly VENV=$APP_DIR/venv
readonly UNIT=/etc/systemd/system/$SERVICE
readonly RULE=/etc/udev/rules.d/99-cablecal.rules
readonly CONF_DIR=/etc/cablecal
readonly CONF=$CONF_DIR/cablecal.toml
readonly ENV_FILE=$CONF_DIR/env
readonly STATE_DIR=/var/lib/cablecal

SRC=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
readonly SRC

say() { printf 'install.sh: %s\n' "$*"; }
die() {
    printf 'install.sh: error: %s\n' "$*" >&2
    exit 1
}
usage() { sed -n '2,/^set -euo/{/^set -euo/d;s/^# \{0,1\}//;p}' "${BASH_SOURCE[0]}"; }

D=""          # destination root; empty: the real system
PIP=1
MODE=install  # install | uninstall | purge
PYTHON=python3

while (($#)); do
    case $1 in
        --destdir)
            (($# >= 2)) || die "--destdir needs a directory"
            D=$2
            shift 2
            ;;
        --destdir=*)
            D=${1#*=}
            shift
            ;;
        --no-pip) PIP=0 && shift ;;
        --uninstall) MODE=uninstall && shift ;;
        --purge) MODE=purge && shift ;;
        --python)
            (($# >= 2)) || die "--python needs an interpreter"
            PYTHON=$2
            shift 2
            ;;
        -h | --help) usage && exit 0 ;;
        *) die "unknown argument: $1 (see --help)" ;;
    esac
done

if [[ -n $D ]]; then
    [[ $D == /* ]] || die "--destdir must be an absolute path, got: $D"
    D=${D%/}
    [[ -n $D ]] || die "--destdir / is the real system: run without --destdir (as root)"
    mkdir -p "$D"
else
    ((EUID == 0)) || die "must run as root (sudo $0), or with --destdir DIR for a test root"
    ((PIP)) || die "--no-pip is only for --destdir test roots: the service needs the venv"
fi

# Commands that change the system outside the destination root: run them for real, or
# print them in --destdir mode.
run() {
    if [[ -n $D ]]; then
        printf 'would run:'
        printf ' %q' "$@"
        printf '\n'
    else
        "$@"
    fi
}

systemd_running() { [[ -z $D && -d /run/systemd/system ]] && command -v systemctl >/dev/null; }

# systemctl/udevadm: printed in --destdir mode, skipped with a note when systemd (or udev)
# is not running, as in a container or a chroot.
systemctl_() {
    if [[ -n $D ]] || systemd_running; then
        run systemctl "$@"
    else
        say "systemd is not running here; skipped: systemctl $*"
    fi
}
udevadm_() {
    if [[ -n $D ]] || { command -v udevadm >/dev/null && [[ -d /run/udev ]]; }; then
        run udevadm "$@"
    else
        say "udev is not running here; skipped: udevadm $*"
    fi
}

nologin_shell() {
    local shell
    for shell in /usr/sbin/nologin /sbin/nologin; do
        [[ -x $shell ]] && echo "$shell" && return
    done
    echo /bin/false
}

ensure_user() {
    getent group dialout >/dev/null || run groupadd --system dialout
    if id -u "$SERVICE_USER" >/dev/null 2>&1; then
        run usermod --append --groups dialout "$SERVICE_USER"
    else
        # Home is the state directory, created by systemd (StateDirectory=), not by useradd.
        run useradd --system --user-group --groups dialout --no-create-home \
            --home-dir "$STATE_DIR" --shell "$(nologin_shell)" \
            --comment "cablecal calibration daemon" "$SERVICE_USER"
    fi
}

install_venv() {
    if ((!PIP)); then
        say "--no-pip: skipped creating $VENV and installing $SRC into it"
        return
    fi
    command -v "$PYTHON" >/dev/null || die "$PYTHON not found (cablecal needs Python >= 3.11)"
    "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' ||
        die "$PYTHON is older than 3.11"
    if [[ -x $D$VENV/bin/python ]] && "$D$VENV/bin/python" -c '' 2>/dev/null; then
        say "upgrading $VENV"
    else
        # Missing, or broken because the system Python it was made from changed.
        say "creating $VENV"
        "$PYTHON" -m venv --clear "$D$VENV"
    fi
    "$D$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade "$SRC"
}

install_files() {
    local example=$SRC/deploy/cablecal.toml.example
    [[ -f $example ]] || die "missing $example"
    install -D -m 0644 "$SRC/deploy/cablecal.service" "$D$UNIT"
    install -D -m 0644 "$SRC/deploy/99-cablecal.rules" "$D$RULE"
    install -d -m 0755 "$D$CONF_DIR"
    install -m 0644 "$example" "$D$CONF.example"
    if [[ -e $D$CONF ]]; then
        say "keeping the existing $CONF (compare with $CONF.example for new settings)"
    else
        install -m 0640 "$example" "$D$CONF"
        run chown "root:$SERVICE_USER" "$D$CONF"
        say "installed $CONF: edit it for this cell"
    fi
    if [[ -e $D$ENV_FILE ]]; then
        say "keeping the existing $ENV_FILE"
    else
        local token
        token=$(od -An -vtx1 -N32 /dev/urandom | tr -d ' \n')
        (
            umask 077
            printf '%s\n' \
                "# Environment of cablecal.service (EnvironmentFile=). Generated by install.sh." \
                "# The bearer token of the REST API's write routes." \
                "CABLECAL_API_TOKEN=$token" >"$D$ENV_FILE"
        )
        chmod 0640 "$D$ENV_FILE"
        run chown "root:$SERVICE_USER" "$D$ENV_FILE"
        say "generated an API token in $ENV_FILE"
    fi
}

do_install() {
    [[ -f $SRC/pyproject.toml ]] || die "$SRC is not the cablecal source tree"
    ensure_user
    install -d -m 0755 "$D$APP_DIR"
    install_venv
    install_files
    systemctl_ daemon-reload
    udevadm_ control --reload
    udevadm_ trigger --action=change --subsystem-match=tty
    systemctl_ enable "$SERVICE"
    # restart, not start: an upgrade must replace the running daemon. Type=notify makes it
    # wait for READY=1, so a daemon that cannot start fails the install here.
    systemctl_ restart "$SERVICE" ||
        die "$SERVICE did not start; see: journalctl -u cablecal -n 50 --no-pager"
    say "done. Status: systemctl status cablecal; logs: journalctl -u cablecal -f"
}

do_uninstall() {
    if [[ -n $D || -e $UNIT ]]; then
        systemctl_ disable --now "$SERVICE" || say "could not stop $SERVICE; continuing"
    fi
    rm -f "$D$UNIT" "$D$RULE"
    rm -rf "$D$APP_DIR"
    systemctl_ daemon-reload
    systemctl_ reset-failed "$SERVICE" 2>/dev/null || true
    udevadm_ control --reload
    if [[ $MODE == purge ]]; then
        rm -rf "$D$STATE_DIR" "$D$CONF_DIR" "$D$UNIT.d"
        if id -u "$SERVICE_USER" >/dev/null 2>&1; then
            run userdel "$SERVICE_USER"
        fi
        say "purged: database, configuration and user removed"
    else
        say "kept $STATE_DIR (database) and $CONF_DIR (configuration); --purge removes them"
    fi
}

[[ -n $D ]] && say "test root $D: files go there; system commands are only printed"
case $MODE in
    install) do_install ;;
    uninstall | purge) do_uninstall ;;
esac
