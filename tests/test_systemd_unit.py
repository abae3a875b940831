"""The shipped unit file, checked by systemd's own tools: ``systemd-analyze verify`` (it parses)
and ``systemd-analyze security --offline=yes`` (how exposed its sandbox leaves the host)."""

import os
import re
import shutil
import subprocess

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
UNIT = os.path.join(REPO, "systemd", "glad-payload.service")
VENV = "/opt/glad-payload/venv"


def _keys(text):
    """section -> key -> list of values (systemd allows repeated keys)."""
    out, section = {}, None
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = out.setdefault(line.strip("[]"), {})
            continue
        key, _, value = line.partition("=")
        section.setdefault(key.strip(), []).append(value.strip())
    return out


MAX_EXPOSURE = 3.0  # issue 20: systemd-analyze security rates the unit <= 3.0


def _analyze():
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze not installed (scripts/install-system-deps.sh)")
    return analyze


def _verify(tmp_path, text):
    """Run verify on a copy whose venv is a temporary one with a real glad-payload executable."""
    analyze = _analyze()
    exe = tmp_path / "venv" / "bin" / "glad-payload"
    exe.parent.mkdir(parents=True)
    exe.write_text("#!/bin/sh\nexit 0\n")
    exe.chmod(0o755)
    unit = tmp_path / "glad-payload.service"
    unit.write_text(text.replace(VENV, str(tmp_path / "venv")))
    proc = subprocess.run([analyze, "verify", str(unit)], capture_output=True, text=True, timeout=60)
    # Lines about other units on this machine are not ours to judge.
    ours = [line for line in (proc.stdout + proc.stderr).splitlines() if "glad-payload" in line]
    return proc.returncode, ours


def test_unit_passes_systemd_analyze_verify(tmp_path):
    with open(UNIT) as handle:
        text = handle.read()
    rc, complaints = _verify(tmp_path, text)
    assert rc == 0 and complaints == [], complaints


def test_verify_would_catch_a_bad_key(tmp_path):
    # Guards the test above: an unknown key (a typo) must show up as a complaint.
    with open(UNIT) as handle:
        text = handle.read().replace("PrivateTmp=yes", "PrivateTmp=yes\nPrivateDevice=no")
    rc, complaints = _verify(tmp_path, text)
    assert any("PrivateDevice" in line for line in complaints), complaints


def test_unit_settings():
    with open(UNIT) as handle:
        keys = _keys(handle.read())
    unit, service, install = keys["Unit"], keys["Service"], keys["Install"]
    assert service["Type"] == ["notify"] and service["NotifyAccess"] == ["main"]
    assert service["ExecStartPre"] == [VENV + "/bin/glad-payload check-config /etc/glad-payload/config.yaml"]
    assert service["ExecStart"] == [VENV + "/bin/glad-payload run --config /etc/glad-payload/config.yaml"]
    assert service["ExecReload"] == ["/bin/kill -HUP $MAINPID"]
    assert service["WatchdogSec"] == ["10"]
    assert service["Restart"] == ["on-failure"] and service["RestartSec"] == ["2"]
    assert service["TimeoutStartSec"] == ["15min"]
    assert service["User"] == ["glad-payload"] and service["Group"] == ["glad-payload"]
    assert service["SupplementaryGroups"] == ["video dialout"]
    assert service["StateDirectory"] == ["glad-payload"] and service["ConfigurationDirectory"] == ["glad-payload"]
    assert "PYTHONUNBUFFERED=1" in service["Environment"]
    for key in ("NoNewPrivileges", "ProtectHome", "PrivateTmp"):
        assert service[key] == ["yes"], key
    assert service["ProtectSystem"] == ["strict"]
    assert "PrivateDevices" not in service  # it would hide the GPU and camera
    assert "DynamicUser" not in service or service["DynamicUser"] == ["no"]
    assert "mavlink-router.service" in unit["After"][0] and "network.target" in unit["After"][0]
    assert "StartLimitIntervalSec" in unit and "StartLimitBurst" in unit
    assert install["WantedBy"] == ["multi-user.target"]


def _exposure(tmp_path, text):
    """The overall exposure systemd-analyze security prints for a unit with this text."""
    unit = tmp_path / "glad-payload.service"
    unit.write_text(text)
    proc = subprocess.run([_analyze(), "security", "--offline=yes", "--no-pager", str(unit)],
                          capture_output=True, text=True, timeout=60)
    found = re.search(r"Overall exposure level for glad-payload.service: ([0-9.]+)", proc.stdout)
    assert found, proc.stdout[-2000:] + proc.stderr
    return float(found.group(1)), proc.stdout


def test_unit_exposure_at_most_3(tmp_path):
    with open(UNIT) as handle:
        exposure, report = _exposure(tmp_path, handle.read())
    assert exposure <= MAX_EXPOSURE, report


def test_exposure_check_catches_a_weak_unit(tmp_path):
    # Guards the test above: the unit without its sandbox (what it was before issue 20, 8.5)
    # must be rated above the limit, so the number parsed is the one that moves.
    with open(UNIT) as handle:
        text = handle.read()
    [service_head, rest] = text.split("# --- Files", 1)
    install = rest[rest.index("[Install]"):]
    weak = service_head + "StateDirectory=glad-payload\nNoNewPrivileges=yes\nProtectSystem=strict\n\n" + install
    exposure, report = _exposure(tmp_path, weak)
    assert exposure > MAX_EXPOSURE + 3, report


def test_sandbox_keeps_camera_gpu_and_uart_reachable():
    with open(UNIT) as handle:
        service = _keys(handle.read())["Service"]
    assert service["DevicePolicy"] == ["closed"]
    allowed = {value.split()[0]: value.split()[1] for value in service["DeviceAllow"]}
    for device in ("char-video4linux", "char-nvhost*", "char-*.gv11b", "/dev/nvmap", "char-ttyTHS"):
        assert allowed.get(device) == "rw", device
    assert "PrivateDevices" not in service and "PrivateNetwork" not in service
    assert service["CapabilityBoundingSet"] == [""]
    assert service["SystemCallFilter"] == ["@system-service", "~@privileged @resources", "sched_setaffinity setpriority"]
    assert service["SystemCallArchitectures"] == ["native"]
    families = service["RestrictAddressFamilies"][0].split()
    assert {"AF_UNIX", "AF_INET", "AF_INET6"} <= set(families)  # sd_notify, MAVLink over UDP
    # CSI cameras: nvargus-daemon's socket in the host's /tmp, through the private /tmp.
    assert service["PrivateTmp"] == ["yes"] and "-/tmp/argus_socket" in service["BindPaths"]
    # The only writable place: engines, outputs, the signing timestamp.
    assert service["ProtectSystem"] == ["strict"] and service["StateDirectory"] == ["glad-payload"]
    assert "ReadWritePaths" not in service
    assert service["MemoryMax"]
