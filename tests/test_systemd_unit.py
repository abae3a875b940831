"""The shipped unit file, checked by systemd's own parser (``systemd-analyze verify``)."""

import os
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


def _verify(tmp_path, text):
    """Run verify on a copy whose venv is a temporary one with a real glad-payload executable."""
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze not installed (apt-get install systemd)")
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
