"""Port helpers: finding U2D2s, the FTDI latency-timer warning, opening ports, and the udev rules."""

import os
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from crane_io.dynamixel.port import open_port
from crane_io.dynamixel.ports import latency_warning, list_u2d2_ports, port_warnings, read_latency_timer
from crane_io.errors import HardwareError

ROOT = Path(__file__).resolve().parents[1]


def _info(device, vid=0x0403, pid=0x6014, serial="FT6Z5Q1I", description="USB <-> Serial Converter"):
    return SimpleNamespace(device=device, vid=vid, pid=pid, serial_number=serial, description=description)


@pytest.fixture
def fake_tree(tmp_path):
    sysfs = tmp_path / "sys"
    dev = tmp_path / "dev"
    for tty, latency in (("ttyUSB0", 16), ("ttyUSB1", 1)):
        d = sysfs / "bus" / "usb-serial" / "devices" / tty
        d.mkdir(parents=True)
        (d / "latency_timer").write_text(f"{latency}\n")
        (dev / tty).parent.mkdir(parents=True, exist_ok=True)
        (dev / tty).write_text("")
    by_id = dev / "serial" / "by-id"
    by_id.mkdir(parents=True)
    (by_id / "usb-FTDI_USB__-__Serial_Converter_FT6Z5Q1I-if00-port0").symlink_to("../../ttyUSB0")
    (by_id / "usb-FTDI_USB__-__Serial_Converter_FT88YWED-if00-port0").symlink_to("../../ttyUSB1")
    return SimpleNamespace(sysfs=str(sysfs), dev=str(dev))


def test_lists_only_u2d2s_with_by_id_serial_and_latency(fake_tree):
    dev = fake_tree.dev
    infos = [_info(f"{dev}/ttyUSB1", serial="FT88YWED"), _info(f"{dev}/ttyUSB0"),
             _info(f"{dev}/ttyACM0", vid=0x2341, pid=0x0043, serial="arduino")]
    ports = list_u2d2_ports(infos, sysfs_root=fake_tree.sysfs, dev_root=dev)
    assert [p.device for p in ports] == [f"{dev}/ttyUSB0", f"{dev}/ttyUSB1"]
    first, second = ports
    assert first.serial_number == "FT6Z5Q1I"
    assert first.by_id.endswith("usb-FTDI_USB__-__Serial_Converter_FT6Z5Q1I-if00-port0")
    assert first.latency_timer_ms == 16 and "16 ms" in first.warning and "latency_timer" in first.warning
    assert second.latency_timer_ms == 1 and second.warning is None
    assert len(list_u2d2_ports(infos, sysfs_root=fake_tree.sysfs, dev_root=dev, all_ports=True)) == 3


def test_no_sysfs_means_no_latency_and_no_warning(tmp_path):
    ports = list_u2d2_ports([_info("/dev/ttyUSB7")], sysfs_root=str(tmp_path), dev_root=str(tmp_path))
    assert ports[0].latency_timer_ms is None and ports[0].warning is None and ports[0].by_id is None


def test_latency_warning_names_the_fix(fake_tree):
    assert read_latency_timer("/dev/ttyUSB0", fake_tree.sysfs) == 16
    warning = latency_warning("/dev/ttyUSB0", 16)
    assert "udev/99-crane-x7.rules" in warning
    assert "/sys/bus/usb-serial/devices/ttyUSB0/latency_timer" in warning
    assert latency_warning("/dev/ttyUSB0", 1) is None
    assert port_warnings(f"{fake_tree.dev}/ttyUSB1", sysfs_root=fake_tree.sysfs) == []
    assert len(port_warnings(f"{fake_tree.dev}/ttyUSB0", sysfs_root=fake_tree.sysfs)) == 1


def test_missing_port_is_one_sentence_pointing_to_crane_collect_ports():
    with pytest.raises(HardwareError, match=r"port /dev/ttyUSB42 does not exist \(is the U2D2 plugged in\? "
                                            r"see `crane-collect ports`\)"):
        open_port("/dev/ttyUSB42", 3_000_000)


def test_a_pty_opens_and_a_second_opener_is_told_it_is_busy():
    master, slave = os.openpty()
    path = os.ttyname(slave)
    try:
        handler = open_port(path, 3_000_000)
        try:
            assert handler.is_open
            handler.writePort(b"\x01\x02")
            assert os.read(master, 2) == b"\x01\x02"
            os.write(master, b"\x03")
            data = b""
            for _ in range(1000):
                data += handler.readPort(1)
                if data:
                    break
            assert data == b"\x03" and handler.bytes_written == 2 and handler.bytes_read == 1
            with pytest.raises(HardwareError, match=f"port {path} is busy"):
                open_port(path, 3_000_000)
        finally:
            handler.closePort()
    finally:
        os.close(master)
        os.close(slave)


def test_unsupported_baud_rate_is_refused():
    with pytest.raises(HardwareError, match="baud rate 123 is not one"):
        open_port("loop://", 123)


def _rules():
    text = (ROOT / "udev" / "99-crane-x7.rules").read_text()
    return [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]


def test_udev_rules_have_every_required_key():
    rules = _rules()
    assert len(rules) >= 2
    for line in rules:
        keys = dict(re.findall(r'([A-Z_]+(?:\{[^}]+\})?)[:+!=]?=\s*"([^"]*)"', line))
        assert keys['SUBSYSTEM'] == "tty"
        assert keys['ATTRS{idVendor}'] == "0403" and keys['ATTRS{idProduct}'] == "6014"
        assert keys['ATTR{device/latency_timer}'] == "1"
        assert keys['ENV{ID_MM_DEVICE_IGNORE}'] == "1"
        assert keys['GROUP'] == "dialout" and keys['MODE'] == "0660"
    links = [re.search(r'SYMLINK\+="([^"]+)"', line) for line in rules]
    named = {m.group(1): line for m, line in zip(links, rules) if m}
    assert set(named) == {"crane_x7_leader", "crane_x7_follower"}
    serials = {re.search(r'ATTRS\{serial\}=="([^"]+)"', line).group(1) for line in named.values()}
    assert len(serials) == 2, "each arm needs its own U2D2 serial"
