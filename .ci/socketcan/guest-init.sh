#!/bin/sh
# PID 1 inside a SocketCAN guest (every backend of .ci/socketcan/run boots with the host's /
# as its root and runs this). $1 is the run's work directory on the host filesystem:
#   env         sourced first: the guest's environment and SOCKETCAN_* settings of the backend
#   cmd         the command, quoted for sh
# It writes there: guard (the vector guard's lines), slowdown (the measured factor), refused
# (why the guard refused this guest), rc (the command's exit code; 125 when it never ran).
# On the console: "socketcan-guest: <what>" lines, then the marker line
# "socketcan-guest: started" right before the command, then the command's own output.
work="$1"
. "$work/env"
say() { echo "socketcan-guest: $*"; }
finish() {
    echo "$1" > "$work/rc.tmp" && mv "$work/rc.tmp" "$work/rc"
    say finished
    sync
    # No init system: power off with reboot(2) directly, whichever tool exists.
    poweroff -f 2>/dev/null
    python3 -c 'import ctypes; ctypes.CDLL(None).reboot(0x4321FEDC)' 2>/dev/null
    echo o > /proc/sysrq-trigger 2>/dev/null
    sleep 60
}

mount -t proc proc /proc
mount -t sysfs sys /sys
# The kernel may have mounted its devtmpfs on /dev already: a tmpfs over it would hide
# /dev/null and /dev/ptmx (pseudo-terminals, which --simulate needs).
mountpoint -q /dev || mount -t devtmpfs dev /dev 2>/dev/null || mount -t tmpfs dev /dev
mkdir -p /dev/shm /dev/pts
mount -t tmpfs shm /dev/shm
mountpoint -q /dev/pts || mount -t devpts -o ptmxmode=0666 devpts /dev/pts 2>/dev/null
[ -e /dev/ptmx ] || ln -s pts/ptmx /dev/ptmx
hostname "$SOCKETCAN_HOSTNAME" 2>/dev/null

# SocketCAN: the backend says how its kernel gets the modules (insmod of files, or modprobe)
ok=1
if [ -n "$SOCKETCAN_INSMOD" ]; then
    for m in $SOCKETCAN_INSMOD; do insmod "$m" || { say "insmod $m failed"; ok=0; }; done
else
    modprobe -a can can_raw can_bcm can_dev vcan || { say "modprobe of the CAN modules failed"; ok=0; }
fi
ip link set lo up
for bus in vcan0 vcan1; do  # vcan1: a second bus for tests that run two devices apart
    ip link add $bus type vcan && ip link set $bus up || ok=0
done
[ $ok = 1 ] || { say "SocketCAN set-up failed"; finish 125; }
say "vcan0 and vcan1 up"
# slcan (a serial-line adapter's driver, tests/socketcan/test_socketcan_slcan.py): optional
if [ -n "$SOCKETCAN_INSMOD_OPTIONAL" ]; then
    for m in $SOCKETCAN_INSMOD_OPTIONAL; do [ -e "$m" ] && insmod "$m" 2>/dev/null; done
elif [ -z "$SOCKETCAN_INSMOD" ]; then
    modprobe slcan 2>/dev/null
fi

# Emulated CAN controllers (QEMU, --can-controllers): the real kernel driver binds each
# device; their interfaces (down, no bit timing yet) go to the tests in
# FIELDGATE_TEST_CAN_CONTROLLERS, in PCI order.
if [ -n "$SOCKETCAN_CONTROLLER_DRIVER" ]; then
    modprobe "$SOCKETCAN_CONTROLLER_DRIVER" || { say "modprobe $SOCKETCAN_CONTROLLER_DRIVER failed"; finish 125; }
    found=""
    for i in $(seq 50); do
        found=""
        for dev in /sys/class/net/*; do
            [ "$(basename "$(readlink "$dev/device/driver" 2>/dev/null)")" = "$SOCKETCAN_CONTROLLER_DRIVER" ] &&
                found="$found ${dev##*/}"
        done
        [ "$(echo $found | wc -w)" -ge "$SOCKETCAN_CONTROLLER_COUNT" ] && break
        sleep 0.1
    done
    found="$(echo $found)"
    [ "$(echo $found | wc -w)" -ge "$SOCKETCAN_CONTROLLER_COUNT" ] ||
        { say "the $SOCKETCAN_CONTROLLER_DRIVER driver bound only '$found'"; finish 125; }
    export FIELDGATE_TEST_CAN_CONTROLLERS="$found"
    say "CAN controllers ($SOCKETCAN_CONTROLLER_DRIVER): $found"
fi

# The vector guard: SSE state must survive; AVX state must too, unless the backend runs
# without XSTATE (SOCKETCAN_NO_XSTATE=1), where the known answers must match the host's.
refuse() { say "REFUSED: $*"; echo "$*" > "$work/refused"; finish 125; }
if [ -n "$SOCKETCAN_GUARD" ]; then
    "$SOCKETCAN_GUARD" > "$work/guard" 2>&1 || refuse "SSE register state is not preserved: $(head -n 1 "$work/guard")"
    grep -qx 'xmm ok (0 bad of [0-9]*)' "$work/guard" || refuse "vector guard output unreadable: $(head -c 200 "$work/guard")"
    if ! grep -q '^ymm ok\|^ymm n/a' "$work/guard"; then
        [ "$SOCKETCAN_NO_XSTATE" = 1 ] || refuse "AVX register state is not preserved: $(grep '^ymm' "$work/guard")"
        answers="$(PYTHONHASHSEED=0 python3 "$SOCKETCAN_KNOWN_ANSWERS" 2>&1 | tail -n 1)"
        echo "$answers" >> "$work/guard"
        [ "$answers" = "known-answers $SOCKETCAN_EXPECTED_ANSWERS" ] ||
            refuse "known answers differ from the host's (vector state corrupted despite SSE-only glibc/OpenSSL): $answers"
    fi
    say "guard: $(tr '\n' ';' < "$work/guard")"
fi

# The slowdown against the host: the same pure-Python work, timed here (the host's time is
# in SOCKETCAN_HOST_CALIBRATION); the tests scale their waits by it.
FIELDGATE_SOCKETCAN_SLOWDOWN="$(python3 "$SOCKETCAN_CALIBRATE" "$SOCKETCAN_HOST_CALIBRATION" 2>/dev/null || echo 1)"
export FIELDGATE_SOCKETCAN_SLOWDOWN
echo "$FIELDGATE_SOCKETCAN_SLOWDOWN" > "$work/slowdown"
say "slowdown $FIELDGATE_SOCKETCAN_SLOWDOWN"

say "started"
sh "$work/cmd" </dev/null
finish $?
