#!/usr/bin/env bash
# System packages the tests need (Debian/Ubuntu): GStreamer for the real-pipeline capture tests,
# the live video and the recording (plugins-bad: openh264enc, BSD-licensed, and h264parse; the
# RTSP server and its typelib; libav: avdec_h264 for the tests' clients), PyGObject's build deps,
# systemd for `systemd-analyze verify`. Skips what is already there. No x264 (GPL).
set -euo pipefail
pkgs=(gstreamer1.0-tools gstreamer1.0-plugins-base gstreamer1.0-plugins-good gstreamer1.0-plugins-bad
      gstreamer1.0-libav gstreamer1.0-rtsp gir1.2-gstreamer-1.0 gir1.2-gst-plugins-base-1.0
      gir1.2-gst-rtsp-server-1.0 libgirepository1.0-dev libcairo2-dev pkg-config python3-dev systemd)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
fi
