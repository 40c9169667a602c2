#!/usr/bin/env bash
# Checks the firmware's build tools: the Arm GCC toolchain with newlib, CMake, a host C++
# compiler (picotool) and Node.js with npm (the emulator). As root with apt-get (CI), the
# missing Debian packages are installed; elsewhere it says what to install and fails.
set -euo pipefail

debian_packages=()
if ! command -v arm-none-eabi-gcc >/dev/null 2>&1 \
        || [[ "$(arm-none-eabi-gcc -print-file-name=libc.a)" == "libc.a" ]]; then
    debian_packages+=(gcc-arm-none-eabi libnewlib-arm-none-eabi libstdc++-arm-none-eabi-newlib)
fi
command -v cmake >/dev/null 2>&1 || debian_packages+=(cmake)
command -v c++ >/dev/null 2>&1 || debian_packages+=(g++)
command -v make >/dev/null 2>&1 || debian_packages+=(make)

if ((${#debian_packages[@]} > 0)); then
    if [[ "$(id -u)" == 0 ]] && command -v apt-get >/dev/null 2>&1; then
        echo "firmware: installing ${debian_packages[*]}" >&2
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -q
        apt-get install -y -q --no-install-recommends "${debian_packages[@]}"
    else
        echo "firmware: missing build tools. Install them (Debian/Ubuntu):" >&2
        echo "    sudo apt-get install ${debian_packages[*]}" >&2
        exit 1
    fi
fi

node_major=0
if command -v node >/dev/null 2>&1; then
    node_major="$(node -p 'process.versions.node.split(".")[0]')"
fi
if ((node_major < 20)) || ! command -v npm >/dev/null 2>&1; then
    echo "firmware: the emulator needs Node.js 20 or later with npm (found: ${node_major:-none})." >&2
    echo "    Install Node.js 20 (e.g. from nodejs.org or your distribution) and npm." >&2
    exit 1
fi
